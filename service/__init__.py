"""The distributed service: REST API, database, storage and the ``mocap serve`` command.

Everything here is a thin layer over ``core``: the workers (``worker/``) call the
same ``core.sequence`` steps as ``mocap fit``; this package only stores, schedules
and serves. The database is the source of truth; Celery messages carry ids.
"""
