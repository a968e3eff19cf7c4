"""Celery workers: thin tasks (``tasks``) over one orchestration module (``orchestration``)."""
