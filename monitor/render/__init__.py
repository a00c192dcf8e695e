"""Pictures of dexel models: Van Hook's image-space shaded view (:mod:`.shaded`, numpy),
colour by meaning and the marks every picture carries (:mod:`.meaning`), pictures of a
recorded run at any stage (:mod:`.runpicture`), pyvista 3-D views (:mod:`.view3d`), the
report's plots (:mod:`.plots`, matplotlib), animations (:mod:`.animate`) and the live
view (:mod:`.live`). pyvista is imported only by the modules that need it."""
