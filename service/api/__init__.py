"""The REST API (FastAPI), versioned under ``/v1``: one router per resource."""
