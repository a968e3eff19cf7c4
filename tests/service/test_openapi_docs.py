"""The OpenAPI description (``/docs``, ``/redoc``) says what every operation does, with examples:
read from ``app.openapi()``, so an endpoint added later without them fails here."""

from __future__ import annotations

from typing import Any

import pytest

from service.api.app import create_app

JSON = "application/json"


@pytest.fixture(scope="module")
def schema() -> dict[str, Any]:
    return create_app().openapi()


def _operations(schema: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    return [(f"{method.upper()} {path}", operation) for path, item in schema["paths"].items()
            for method, operation in item.items()]


def _has_example(media: dict[str, Any], schema: dict[str, Any]) -> bool:
    """An example on the media type, or on the schema it names (following ``$ref``, and an
    optional body's ``anyOf`` [schema, null])."""
    if "example" in media or "examples" in media:
        return True
    target = media.get("schema", {})
    target = next((s for s in target.get("anyOf", []) if "$ref" in s), target)
    while "$ref" in target:
        target = schema["components"]["schemas"][target["$ref"].rsplit("/", 1)[1]]
    return bool(target.get("examples") or "example" in target)


def test_every_operation_says_what_it_does(schema):
    operations = _operations(schema)
    assert len(operations) == 29  # 26 + DELETE of models, rigs and videos
    undescribed = [name for name, op in operations if len(op.get("description", "")) < 40]
    assert undescribed == []
    without_example = [name for name, op in operations if "Example" not in op["description"]]
    assert without_example == []


def test_every_json_request_and_response_has_an_example(schema):
    missing = []
    for name, operation in _operations(schema):
        bodies = {"request": operation.get("requestBody", {}).get("content", {})}
        bodies.update({status: response.get("content", {})
                       for status, response in operation["responses"].items()})
        missing += [f"{name} {where}" for where, content in bodies.items()
                    if JSON in content and not _has_example(content[JSON], schema)]
    assert missing == []


def test_errors_are_described_as_the_api_sends_them(schema):
    """Every 4xx the description lists is the API's ``{"detail": "..."}``, not FastAPI's default
    validation error shape, which this API never sends."""
    assert "HTTPValidationError" not in schema["components"]["schemas"]
    for name, operation in _operations(schema):
        for status, response in operation["responses"].items():
            if status.startswith("4"):
                assert response["content"][JSON]["schema"] == {"$ref": "#/components/schemas/Problem"}, \
                    (name, status)


def test_the_examples_fit_their_schemas():
    """Each schema's example validates against its own Pydantic model (a stale example, e.g.
    after a field is renamed, fails here). Read from the models: the published description
    drops the example's null fields (FastAPI writes it with ``exclude_none``)."""
    from pydantic import BaseModel

    from service import schemas

    models = [m for m in vars(schemas).values()
              if isinstance(m, type) and issubclass(m, BaseModel) and m.__module__ == schemas.__name__]
    for model in models:
        extra = model.model_config.get("json_schema_extra")
        assert isinstance(extra, dict) and extra["examples"], model.__name__
        model.model_validate(extra["examples"][0])
    assert len(models) >= 20
