"""Benchmarks: speed, scaling, memory and accuracy on the synthetic world (issue 9), and soak.

One module per benchmark, each exposing ``run(options: BenchOptions) -> dict`` (JSON-ready, a
piece that cannot run yet is ``{'skipped': reason}``); :mod:`.runner` runs each in its own
process pinned to one core and gathers the results (``face-tracking bench``).
"""
