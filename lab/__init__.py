"""What researchers and we run to measure: experiments, benchmarks, figures.

It may import every other package; nothing imports it but the ``ankle`` command.
"""
