"""The ``mocap`` command line (typer and rich): ``cli.app`` holds the commands on ``core``.

Kept out of ``core`` so that the science library imports neither typer nor rich; the
console script (``service.cli``) adds the service's commands to :data:`cli.app.app`.
"""
