"""Tuning a registered optimiser with Optuna: the ``tune`` command's machinery.

:mod:`.settings` declares what a tuning is (:class:`~.settings.TuningSettings`) and the data
it may not touch; :mod:`.space` builds the search space from the ``search=`` declarations of
an optimiser's settings; :mod:`.objectives` evaluates one configuration (per solve on the
library's validation split, or closed loop over validation seeds); :mod:`.study` runs the
seeded, resumable study; :mod:`.variants` writes the tuned-variant file that
:mod:`formation_bench.optimizers.tuned` registers.

Optuna (the ``tune`` extra) is imported only by the modules that need it, when a tuning
runs: importing ``formation_bench`` does not import it.
"""
