"""starnav.navigation.trn: terrain-relative navigation of an asteroid fly-by from tracker windows
(the seed paper's third algorithm).

Front end (:mod:`~starnav.navigation.trn.windows`, :mod:`~starnav.navigation.trn.features`,
:mod:`~starnav.navigation.trn.frontend`; truth for metrics in
:mod:`~starnav.navigation.trn.truth`; run on rendered frames by :mod:`starnav.simulate.trn`):
a segments read finds the lit body, up to 16 windows are placed where trackable texture is
predicted, features are detected and tracked inside the windows only. Its output per frame is a
:class:`~starnav.navigation.trn.measurements.FlybyMeasurement`. Back end
(:mod:`~starnav.navigation.trn.filter`): the estimator of the spacecraft's position and
velocity relative to the body from those measurements.
"""
