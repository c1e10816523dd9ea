"""pf_slam_tools: the development side of pf_slam, outside the runtime package.

``sim``: seeded simulators that write bags with ground truth (indoor floors, KAIST-layout car
drives). ``bench``: the benchmarks behind ``pf-slam bench`` and ``make bench*``, which write their
own tables into ``docs/results.md``. Installed by ``make setup``; the ``pf-slam simulate*``,
``texture`` and ``bench`` subcommands import it lazily.
"""
