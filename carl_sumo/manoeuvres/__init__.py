"""Manoeuvres: cut-ins, cut-outs, joins and merges around a platoon, in one package.

- :mod:`~carl_sumo.manoeuvres.spec`: what a manoeuvre is (``--scenario cut-in:k=3:t=8`` ...);
- :mod:`~carl_sumo.manoeuvres.simulation`: running one in SUMO (the entering or leaving vehicle,
  the chain re-formed behind it);
- :mod:`~carl_sumo.manoeuvres.metrics`: the manoeuvre's own metrics (peak braking, settling, TTC);
- :mod:`~carl_sumo.manoeuvres.runs`: a controller on many events with a manoeuvre each;
- :mod:`~carl_sumo.manoeuvres.tables`, :mod:`~carl_sumo.manoeuvres.criterion`,
  :mod:`~carl_sumo.manoeuvres.figures`: ``evaluate --suite scenarios``, its paired criterion and
  its figures.

Imports ``experiments`` and below.
"""
