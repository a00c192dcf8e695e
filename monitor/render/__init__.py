"""Pictures of dexel models: Van Hook's image-space shaded view (:mod:`.shaded`, numpy),
pyvista 3-D views (:mod:`.view3d`), animations (:mod:`.animate`) and the live view
(:mod:`.live`). pyvista is imported only by the modules that need it."""
