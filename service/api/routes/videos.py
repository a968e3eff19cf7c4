"""Trial videos: streamed to storage, probed, registered only when complete and decodable."""

from __future__ import annotations

import base64
from dataclasses import replace

import cv2
from fastapi import APIRouter, Request, Response
from fastapi.concurrency import run_in_threadpool

from core.detect import DetectorParams
from core.preview import preview_frame
from core.rig import Rig, RigError
from core.video import VideoError, VideoSet
from service import crud, limits
from service.api.deps import (
    CONFLICT,
    CurrentLab,
    Cursor,
    Limit,
    MetadataQuery,
    NameQuery,
    PathId,
    SessionDep,
    SettingsDep,
    StorageDep,
)
from service.errors import InvalidError
from service.models import RigRow, Video
from service.schemas import DetectPreview, DetectPreviewCreate, VideoPage, VideoPublic, labels_from_query
from service.upload import FILE_BODY, MULTIPART_SLACK, check_length, declared_length, receive_video

router = APIRouter(prefix="/videos", tags=["videos"])


def _public(row: Video) -> VideoPublic:
    return VideoPublic(id=row.id, filename=row.filename, name=row.name, metadata=row.meta, frames=row.frames,
                       announced_frames=row.announced_frames, warning=crud.missing_frames(row), fps=row.fps,
                       width=row.width, height=row.height, size_bytes=row.size_bytes, sha256=row.sha256,
                       created_at=row.created_at)


@router.post("", status_code=201, response_model=VideoPublic,
             summary="Upload a video (multipart field 'file'); 413 past MOCAP_MAX_UPLOAD_BYTES, "
             "429 past the lab's hourly upload limits", openapi_extra=FILE_BODY)
async def upload_video(request: Request, session: SessionDep, storage: StorageDep,
                       settings: SettingsDep, lab: CurrentLab, name: NameQuery = None,
                       metadata: MetadataQuery = None) -> VideoPublic:
    """Stream a trial video (multipart field ``file``) to storage; it is registered once fully
    stored and decodable (422 naming the file otherwise). ``?name=`` and ``?metadata=`` (a JSON
    object) label it. 413 past ``MOCAP_MAX_UPLOAD_BYTES``, 429 past the lab's hourly limits.
    Example: ``curl -H "$H" -F file=@trial1_cam0.avi "$API/videos?name=walk-07"``"""
    checked_name, meta = labels_from_query(name, metadata)
    # Refused before a byte is read when the lab is already over its hourly limits (the declared
    # length less the multipart overhead: never more than the file; checked exactly on registering).
    check_length(request, settings.max_upload_bytes + MULTIPART_SLACK)  # 413 before 429: never fits
    incoming = max(0, declared_length(request) - MULTIPART_SLACK)
    await run_in_threadpool(limits.check_upload, session, lab, settings, incoming)
    # End the transaction while the body streams (minutes): on SQLite it holds the write lock.
    session.rollback()
    got = await receive_video(request, storage, settings.max_upload_bytes)
    row = await run_in_threadpool(crud.register_video, session, storage, lab, settings, key=got.key,
                                  filename=got.filename, size=got.size, sha256=got.sha256,
                                  name=checked_name, meta=meta)
    return _public(row)


@router.get("", response_model=VideoPage, summary="The lab's videos, newest first")
def list_videos(session: SessionDep, lab: CurrentLab, cursor: Cursor = None, limit: Limit = 50) -> VideoPage:
    """The lab's videos, newest first, ``limit`` per page; pass ``next_cursor`` as ``?cursor=``
    for the next page. Example: ``GET /v1/videos?limit=50``"""
    rows, next_cursor = crud.list_owned(session, Video, lab, cursor=cursor, limit=limit)
    return VideoPage(items=[_public(row) for row in rows], next_cursor=next_cursor)


@router.get("/{video_id}", response_model=VideoPublic)
def get_video(video_id: PathId, session: SessionDep, lab: CurrentLab) -> VideoPublic:
    """One video of the lab: what the probe found (frames, fps, size), its upload name, name and
    metadata. Example: ``GET /v1/videos/1``"""
    return _public(crud.owned(session, Video, video_id, lab))


@router.delete("/{video_id}", status_code=204, response_class=Response, responses=CONFLICT)
def delete_video(video_id: PathId, session: SessionDep, storage: StorageDep, lab: CurrentLab) -> Response:
    """Delete the video and its stored file (204). 409, naming the jobs, while any job, finished
    or not, names it (its report names the video). Example: ``curl -X DELETE -H "$H" $API/videos/1``"""
    crud.delete_upload(session, storage, lab, Video, video_id)
    return Response(status_code=204)


# ---- seeing the fit: detection preview (core.preview; docs/SEEING_THE_FIT.md) ----


@router.post("/{video_id}/detect-preview", response_model=DetectPreview,
             summary="Detect markers in one frame with given detector options: counts, centroids and "
             "an image of rois, mask and centroids (to choose options before a job)")
def detect_preview(video_id: PathId, session: SessionDep, storage: StorageDep, lab: CurrentLab,
                   body: DetectPreviewCreate | None = None) -> DetectPreview:
    """Run marker detection on one frame with the given detector options and the rig's views of
    this video: counts and centroids per view, and a PNG of rois, mask and centroids, to choose
    options before submitting a job. Example: ``POST /v1/videos/1/detect-preview`` with
    ``{"rig_id": 1, "frame": 0}``"""
    video = crud.owned(session, Video, video_id, lab)  # another lab's video: 404 before the body's 422
    if body is None:
        raise InvalidError('a JSON body naming the rig is required: {"rig_id": ...}')
    rig = Rig.from_dict(crud.owned(session, RigRow, body.rig_id, lab).spec)
    views = tuple(replace(v, video=0) for v in rig.views if v.video == body.video_index)
    if not views:
        raise InvalidError(f"rig {body.rig_id} has no view in video {body.video_index}")
    if body.frame >= video.frames:
        raise InvalidError(f"frame {body.frame} is past the {video.frames} frames of video {video_id} "
                           f"({video.filename})")
    try:
        params = DetectorParams(**body.detector.model_dump())
    except ValueError as exc:
        raise InvalidError(f"detector: {exc}") from None
    name = f"video {video_id} ({video.filename})"
    try:
        Rig(views).check_videos([(video.width, video.height)])
        (frames,) = VideoSet([storage.path(video.storage_key)]).read(body.frame, body.frame + 1)
    except RigError as exc:
        raise InvalidError(f"rig {body.rig_id} and {name}: {exc}") from None
    except VideoError:  # its message names the server's path: not shown
        raise InvalidError(f"frame {body.frame} of {name} does not decode") from None
    drawn, found, levels = preview_frame(frames, rig=Rig(views), params=params)
    png = cv2.imencode(".png", drawn[0])[1].tobytes()
    return DetectPreview(
        video_id=video_id, rig_id=body.rig_id, frame=body.frame,
        counts={v.name: int(n) for v, n in zip(views, found.counts, strict=True)},
        thresholds={v.name: level for v, level in zip(views, levels, strict=True)},
        centroids={v.name: found.view(i).round(3).tolist() for i, v in enumerate(views)},
        image="data:image/png;base64," + base64.b64encode(png).decode(),
    )
