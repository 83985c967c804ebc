"""The ``rig`` command line: one module per command group (``serve``, ``process``, ``record``,
``devices``, ``calibrate``, ``lut``, ``sim``, ``evaluate``), mounted by :mod:`cli.main`.

Imports flow one way: ``cli`` → ``service`` → ``rig`` → ``calibration``. Only this package uses
typer and rich; the others report progress through callbacks and fail by raising their own
exceptions, which :mod:`cli.errors` turns into one line and an exit status.
"""
