"""What a tracker sees.

* :mod:`~starforge.tracking.bodies`: rigid bodies (mm) from families, placements and a lab's
  tracker files (``load_bodies``, also behind ``stars --avoid`` and ``place --avoid``)
* :mod:`~starforge.tracking.identify`: vectorised tracker-style identification and simulation
* :mod:`~starforge.tracking.check`: the ``starforge check`` report (check.json)
* accuracy (TRE, rotation error) and Kabsch fits live in :mod:`starforge.geometry.rigid`
* :mod:`~starforge.tracking.presets`: vendor presets (templates/presets) and named rule checks
* :mod:`~starforge.tracking.formats`: the registry of tracker formats (QTM, VSK, Atracsys,
  NDI .rom, OptiTrack Motive, CSV), a reader and a writer each
* :mod:`~starforge.tracking.export`: a body set written in tracker formats (``export``)
* :mod:`~starforge.tracking.tolerances`: the tolerances vendor files get, from the noise and
  the bodies' margins
* :mod:`~starforge.tracking.sweep`: capacity curves (``starforge sweep``)

Heavy imports (scipy, matplotlib) stay inside functions.
"""
