"""Collision-detection experiments (thesis chapter 4): the benchmark of
``mcpilco-bench-collision`` (:mod:`.bench`, :mod:`.data`, :mod:`.report`), the quasi-static
friction experiment (:mod:`.quasi_static_friction`) and the nominal arms the detectors are
trained with (:mod:`.nominal`). The detection tool itself is
:mod:`mcpilco.models.collision.detect`."""
