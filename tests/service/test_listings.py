"""The lab's uploads listed (``GET /v1/models``, ``/v1/rigs``, ``/v1/videos``): newest first, paged, the
lab's own only."""

from __future__ import annotations

import pytest
from svc_helpers import upload_inputs

pytestmark = [pytest.mark.service]


@pytest.fixture(scope="module")
def uploads(embedded, clip):
    """Lab "lister" with two uploads of each kind (the second set newest)."""
    client = embedded.create_lab("lister")
    return client, [upload_inputs(client, clip.video) for _ in range(2)]


@pytest.mark.parametrize("kind", ["models", "rigs", "videos"])
def test_uploads_are_listed_newest_first_a_page_at_a_time(uploads, kind):
    client, (older, newer) = uploads
    field = f"{kind[:-1]}_id"
    first = client.get(f"/{kind}", params={"limit": 1}).json()
    assert [item["id"] for item in first["items"]] == [newer[field]]
    assert first["next_cursor"] == newer[field]
    second = client.get(f"/{kind}", params={"limit": 1, "cursor": first["next_cursor"]}).json()
    assert [item["id"] for item in second["items"]] == [older[field]]
    assert second["next_cursor"] is None
    whole = client.get(f"/{kind}").json()
    assert [item["id"] for item in whole["items"]] == [newer[field], older[field]]
    assert whole["items"][0] == client.get(f"/{kind}/{newer[field]}").json()  # same fields as a read


def test_a_listing_shows_the_metadata_of_each_upload(uploads, clip):
    client, _ = uploads
    model = client.get("/models").json()["items"][0]
    assert (model["name"], model["dofs"], model["histogram_versions"]) == \
        ("locust_hind_leg", clip.model.dof_names, 1)
    rig = client.get("/rigs").json()["items"][0]
    assert (rig["views"], rig["videos"]) == ([v.name for v in clip.rig.views], 1)
    video = client.get("/videos").json()["items"][0]
    assert (video["filename"], video["frames"], video["width"], video["height"]) == \
        (clip.video.name, 40, 720, 576)
    assert video["size_bytes"] == clip.video.stat().st_size
    assert video["created_at"].endswith(("Z", "+00:00"))


@pytest.mark.parametrize("kind", ["models", "rigs", "videos"])
def test_another_lab_lists_none_of_them(embedded, uploads, kind):
    other = embedded.create_lab("lister-other")
    assert other.get(f"/{kind}").json() == {"items": [], "next_cursor": None}


@pytest.mark.parametrize("query", [{"limit": 0}, {"limit": 201}, {"cursor": 0}, {"cursor": 2**31}])
def test_a_page_out_of_range_is_422_naming_the_parameter(uploads, query):
    client, _ = uploads
    response = client.get("/videos", params=query)
    assert response.status_code == 422
    assert next(iter(query)) in response.json()["detail"]
