"""Full body from VR trackers, the workflow side: :mod:`workflows.tracking.run` (a smplik-trackers file -> an
animation, exported like ``scene animate``'s) and :mod:`workflows.tracking.cli` (``smplik track``). The model and
its runtime are in :mod:`smplik.tracking`."""
