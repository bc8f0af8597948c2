"""Benchmarks of run time against error (``usdbtf bench``).

* :mod:`.suite`      configurations and one run over the sections (report, CSV, plots, JSON);
* :mod:`.sections`   the registry: one module per section (``compress``, ``scaling``,
                     ``quilt``, ``render``);
* :mod:`.methods`    what is compared: ``usdbtf compress`` solver x codec x k and the baselines
                     of :mod:`.baselines` (JPEG per image, per-view PCA, H.265 video);
* :mod:`.heldout`    held-out light directions and their prediction from fitted ones;
* :mod:`.datasets`   cached synthetic inputs and subset manifests;
* :mod:`.measure`, :mod:`.machine`, :mod:`.report`: timing and memory of subprocesses, the
                     machine description, tables, Pareto fronts, fits and plots.

The scripts in ``benchmarks/`` use the same helpers.
"""
