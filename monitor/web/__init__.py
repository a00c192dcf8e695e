"""The browser view: a local page (trame, trame-vtk, trame-vuetify) on a recorded run
(``dexmon view RUN``) or a running job (``dexmon live|dry-run --web``).

One job per module: :mod:`.address` (where to listen), :mod:`.runmodel` (what a run file
says, stage by stage), :mod:`.scene` (the pyvista scene the page shows), :mod:`.page`
(the page and what its controls do), :mod:`.server` (the trame server on its own thread),
:mod:`.live` (a running session's states fed to the page).
"""
