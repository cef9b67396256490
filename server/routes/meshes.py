"""/v1/meshes: upload, list, inspect, fetch levels, split streams and textures, delete.

Levels, split streams and textures of a built mesh never change (a .qpm key names one
build), so their responses carry a strong ETag derived from the .qpm key, the level and
the format (and the split stream's version, whose frames and grids the msgpack levels
and streams follow), are cacheable for a year, and answer ``If-None-Match`` with 304
without loading anything (a texture once its mesh is known to have one).

The read endpoints are the hot path: with the record, the level or the stored stream in
memory (`ReadPath`), they answer on the event loop with bytes already made; only a miss
goes to a worker thread (database, blob store, extraction).
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Header, Query, Request, Response
from starlette.concurrency import run_in_threadpool

import qem_core
from qem_core import codecs
from qem_core import stream as split_stream

from .. import __version__
from ..deps import (
    JobsDep,
    KnownQueryOnly,
    ReadsDep,
    SettingsDep,
    SingleQueryValues,
    StorageDep,
    WriterDep,
)
from ..problems import Problem, problem_responses
from ..ranges import byte_range, if_range_holds
from ..read_path import ReadPath
from ..schemas import (
    LOD_FORMATS,
    LodFormat,
    MeshInfo,
    MeshList,
    UploadAccepted,
    UploadParams,
    mesh_info,
    upload_options,
)
from ..storage import MeshRecord, new_mesh_id, upload_key
from ..uploads import (
    check_file_name,
    receive_upload,
    register_upload,
)

__all__ = ["router"]

router = APIRouter(prefix="/v1/meshes", tags=["meshes"], dependencies=[SingleQueryValues])

IMMUTABLE = "public, max-age=31536000, immutable"
LOD_HEADERS = ("ETag", "X-Lod-Vertices", "X-Lod-Faces", "X-Lod-Error")
SPLIT_HEADERS = ("ETag", "X-Splits-From", "X-Splits-To")
STREAM_MEDIA_TYPE = split_stream.MEDIA_TYPE

_UPLOAD_BODY = {
    "required": True,
    "content": {
        "multipart/form-data": {
            "schema": {
                "type": "object",
                "properties": {"file": {"type": "string", "format": "binary", "minLength": 1}},
                "required": ["file"],
            }
        },
        # An empty file is refused (400): no mesh is empty.
        "application/octet-stream": {
            "schema": {"type": "string", "format": "binary", "minLength": 1}
        },
    },
}


def _find(storage, mesh_id: str) -> MeshRecord:
    record = storage.metadata.get(mesh_id)
    if record is None:
        raise Problem("mesh-not-found", f"no mesh has id {mesh_id!r}")
    return record


async def _find_ready(reads: ReadPath, mesh_id: str) -> MeshRecord:
    """The record of a ready mesh: from memory, else from the database (in a thread);
    a problem when it is missing, failed or not built yet."""
    record = reads.cached_record(mesh_id)
    if record is not None:
        return record
    record = await run_in_threadpool(reads.record, mesh_id)
    if record is None:
        raise Problem("mesh-not-found", f"no mesh has id {mesh_id!r}")
    if record.status == "failed":
        raise Problem(
            "mesh-failed",
            f"mesh {mesh_id} could not be built: {record.error}",
            reason=record.error,
        )
    if record.status != "ready":
        raise Problem(
            "mesh-not-ready",
            f"mesh {mesh_id} is {record.status} ({record.progress:.0%}); retry when its "
            f"status is 'ready'",
            headers={"Retry-After": "1"},
            mesh_status=record.status,
            progress=record.progress,
        )
    return record


def clamp_count(record: MeshRecord, n: int | None) -> int:
    assert record.n_base is not None and record.n_vertices is not None
    if n is None:
        return record.n_vertices
    return min(max(n, record.n_base), record.n_vertices)


@functools.lru_cache(maxsize=4096)
def _build_tag(qpm_key: str | None) -> str:
    """A name for one build as served by this version of the server (hashed once)."""
    return hashlib.sha256(f"{__version__}|{qpm_key}".encode()).hexdigest()[:24]


def _etag(record: MeshRecord, *parts: object) -> str:
    return '"' + "-".join((_build_tag(record.qpm_key), *map(str, parts))) + '"'


def _matches(if_none_match: str | None, etag: str) -> bool:
    """If-None-Match uses the weak comparison (RFC 9110, 13.1.2)."""
    if not if_none_match:
        return False
    if if_none_match.strip() == "*":
        return True
    return any(tag.strip().removeprefix("W/") == etag for tag in if_none_match.split(","))


def _not_modified(etag: str, headers: dict[str, str]) -> Response:
    return Response(status_code=304, headers={"ETag": etag, "Cache-Control": IMMUTABLE, **headers})


@router.post(
    "",
    status_code=202,
    response_model=UploadAccepted,
    summary="Upload a mesh and queue its build",
    responses=problem_responses(400, 401, 403, 413, 415, 422),
    openapi_extra={"requestBody": _UPLOAD_BODY},
)
async def upload_mesh(
    request: Request,
    response: Response,
    params: Annotated[UploadParams, Query()],
    _: WriterDep,
    settings: SettingsDep,
    storage: StorageDep,
    jobs: JobsDep,
) -> UploadAccepted:
    """The mesh (PLY, OBJ, STL, OFF or GLB, or a zip archive of one model with the files
    it names: an OBJ with its .mtl and images) as the multipart field ``file``, or as the
    raw body with ``?name=`` giving its file name. Build options go in the query. The
    file is parsed by the build; follow ``GET /v1/meshes/{id}`` until ``ready`` or
    ``failed``."""
    options = upload_options(params)
    qem_core.BuildOptions.from_mapping(options)  # refuse bad options before the upload
    name = check_file_name(params.name)
    mesh_id = new_mesh_id()
    writer = await run_in_threadpool(storage.blobs.writer, upload_key(mesh_id))
    try:
        given_name = await receive_upload(request, writer, settings.max_upload_bytes)
        if name is None:
            name = check_file_name(given_name, strict=False)
        await run_in_threadpool(writer.commit)
    except BaseException:
        await run_in_threadpool(writer.abort)
        raise
    record = await run_in_threadpool(
        lambda: register_upload(
            storage,
            jobs,
            mesh_id=mesh_id,
            name=name or "upload",
            size=writer.size,
            options=options,
        )
    )
    url = f"/v1/meshes/{record.id}"
    response.headers["Location"] = url
    return UploadAccepted(id=record.id, url=url)


@router.get(
    "",
    response_model=MeshList,
    summary="List meshes with their status",
    dependencies=[KnownQueryOnly],
)
def list_meshes(storage: StorageDep) -> MeshList:
    return MeshList(meshes=[mesh_info(record) for record in storage.metadata.records()])


@router.get(
    "/{mesh_id}",
    dependencies=[KnownQueryOnly],
    response_model=MeshInfo,
    summary="Metadata and build status of a mesh",
    responses=problem_responses(404),
)
def get_mesh(mesh_id: str, storage: StorageDep, response: Response) -> MeshInfo:
    response.headers["Cache-Control"] = "no-cache"
    return mesh_info(_find(storage, mesh_id))


@router.get(
    "/{mesh_id}/lod",
    dependencies=[KnownQueryOnly],
    summary="The mesh at a level of detail",
    response_class=Response,
    responses={
        200: {
            "description": "the mesh with exactly X-Lod-Vertices vertices",
            "content": {codecs.MEDIA_TYPES[f]: {} for f in LOD_FORMATS},
        },
        304: {"description": "not modified (If-None-Match)"},
        **problem_responses(404, 409, 422),
    },
)
async def get_lod(
    mesh_id: str,
    reads: ReadsDep,
    vertices: Annotated[
        int | None,
        Query(
            ge=1,
            description="vertex count; clamped into [min_vertices, vertices] (the served "
            "count is in X-Lod-Vertices); default: the full mesh",
        ),
    ] = None,
    format: Annotated[LodFormat, Query(description="encoding of the mesh")] = "ply",
    if_none_match: Annotated[str | None, Header()] = None,
) -> Response:
    record = await _find_ready(reads, mesh_id)
    n = clamp_count(record, vertices)
    etag = _etag(record, "lod", n, format, split_stream.STREAM_VERSION)
    if _matches(if_none_match, etag):
        return _not_modified(etag, {"X-Lod-Vertices": str(n)})
    lod = reads.levels.cached_lod(record, n, format)
    if lod is None:
        lod = await run_in_threadpool(reads.load, reads.levels.lod, record, n, format)
    return Response(
        lod.content, media_type=codecs.MEDIA_TYPES[format], headers=lod_headers(record, n, lod)
    )


def lod_headers(record: MeshRecord, n: int, lod) -> dict[str, str]:
    """The headers of a level's 200 answer (the route's and the in-memory path's)."""
    stem = Path(record.name).stem or record.id
    return {
        "ETag": _etag(record, "lod", n, lod.format, split_stream.STREAM_VERSION),
        "Cache-Control": IMMUTABLE,
        "X-Lod-Vertices": str(lod.n_vertices),
        "X-Lod-Faces": str(lod.n_faces),
        "X-Lod-Error": repr(lod.error),
        "Content-Disposition": f'inline; filename="{_header_safe(stem)}-{n}.{lod.format}"',
    }


@router.get(
    "/{mesh_id}/splits",
    dependencies=[KnownQueryOnly],
    summary="The vertex splits refining one level to another: stored bytes, Range honoured",
    response_class=Response,
    responses={
        200: {
            "description": "msgpack frames of vertex splits (see docs/formats.md): the run "
            "of the mesh's stored frames that covers [from, to], its real range in "
            "X-Splits-From and X-Splits-To",
            "content": {STREAM_MEDIA_TYPE: {}},
        },
        206: {"description": "the bytes a Range header asked for (Content-Range)"},
        304: {"description": "not modified (If-None-Match)"},
        **problem_responses(400, 404, 409, 416, 422),
    },
)
async def get_splits(
    mesh_id: str,
    reads: ReadsDep,
    from_: Annotated[
        int | None,
        Query(alias="from", ge=1, description="vertex count held; default: the base mesh"),
    ] = None,
    to: Annotated[
        int | None,
        Query(ge=1, description="vertex count wanted; default: the full mesh"),
    ] = None,
    if_none_match: Annotated[str | None, Header()] = None,
    range_: Annotated[
        str | None, Header(alias="Range", description="one byte range, e.g. bytes=1000-")
    ] = None,
    if_range: Annotated[str | None, Header()] = None,
) -> Response:
    """The frames are stored when the mesh is built, every one decodable given only the
    level it refines; the answer is the smallest run of them covering ``from``..``to``,
    so it may start below ``from`` and end above ``to`` (X-Splits-From, X-Splits-To):
    a client skips the splits it holds, and moves its level down to ``to`` if it wants
    exactly that."""
    record = await _find_ready(reads, mesh_id)
    assert record.n_base is not None
    n1 = clamp_count(record, record.n_base if from_ is None else from_)
    n2 = clamp_count(record, to)
    if n1 > n2:
        raise Problem(
            "invalid-request",
            f"from={n1} is above to={n2} (after clamping into [{record.n_base}, "
            f"{record.n_vertices}]); splits only refine, so ask for lod?vertices={n2}",
        )
    stream = reads.streams.cached(record)
    if stream is None:
        stream = await run_in_threadpool(reads.load, reads.streams.get, record)
    headers, body = splits_answer(record, stream, n1, n2)
    etag = headers["ETag"]
    if _matches(if_none_match, etag):
        return _not_modified(etag, headers)
    part = byte_range(range_, len(body)) if if_range_holds(if_range, etag) else None
    if part is None:
        return Response(body, media_type=STREAM_MEDIA_TYPE, headers=headers)
    low, high = part
    headers["Content-Range"] = f"bytes {low}-{high - 1}/{len(body)}"
    return Response(body[low:high], 206, media_type=STREAM_MEDIA_TYPE, headers=headers)


def splits_answer(record: MeshRecord, stream, n1: int, n2: int) -> tuple[dict[str, str], bytes]:
    """The headers and bytes of the stored run covering n1..n2 (clamped, n1 <= n2)."""
    index = stream.index
    first, last = index.covering(n1, n2)
    if first == last:
        served_from = served_to = n1
    else:
        served_from, served_to = index.vertices[first], index.vertices[last]
    headers = {
        "ETag": _etag(record, "splits", split_stream.STREAM_VERSION, served_from, served_to),
        "Cache-Control": IMMUTABLE,
        "Accept-Ranges": "bytes",
        "X-Splits-From": str(served_from),
        "X-Splits-To": str(served_to),
    }
    start, stop = index.byte_span(first, last)
    body = stream.data if stop - start == len(stream.data) else stream.data[start:stop]
    return headers, body


@router.get(
    "/{mesh_id}/texture",
    dependencies=[KnownQueryOnly],
    summary="The texture image of a mesh",
    response_class=Response,
    responses={
        200: {
            "description": "the image the mesh's UVs refer to, as uploaded (PNG, JPEG or WebP)",
            "content": {"image/png": {}, "image/jpeg": {}, "image/webp": {}},
        },
        304: {"description": "not modified (If-None-Match)"},
        **problem_responses(404, 409),
    },
)
async def get_texture(
    mesh_id: str,
    reads: ReadsDep,
    material: Annotated[
        int | None,
        Query(
            ge=0,
            le=qem_core.MAX_MATERIALS - 1,
            description="for a mesh of several materials: which one's image (0-based)",
        ),
    ] = None,
    if_none_match: Annotated[str | None, Header()] = None,
) -> Response:
    """The texture of a mesh uploaded with one (a GLB with its image, an OBJ with its
    .mtl and image in a zip): the image that the UVs of every level refer to, also
    embedded in its GLB and msgpack levels. A mesh of several materials has an image per
    textured material: ``material=k`` names one (the mesh's ``materials`` list gives their
    order). A 404 problem ``texture-not-found`` when there is no such image."""
    record = await _find_ready(reads, mesh_id)
    # Whether there is a texture first: ``If-None-Match: *`` on a mesh without one is a
    # 404, not a 304 (the progressive mesh is cached, so this rarely loads anything).
    pm = await run_in_threadpool(reads.load, reads.levels.progressive_mesh, record)
    try:
        image, media_type = pm.texture_image(material)
    except LookupError as error:
        raise Problem("texture-not-found", f"mesh {mesh_id}: {error}") from None
    etag = _etag(record, "texture") if material is None else _etag(record, "texture", material)
    if _matches(if_none_match, etag):
        return _not_modified(etag, {})
    return Response(
        image,
        media_type=media_type,
        headers={"ETag": etag, "Cache-Control": IMMUTABLE, "X-Content-Type-Options": "nosniff"},
    )


@router.delete(
    "/{mesh_id}",
    dependencies=[KnownQueryOnly],
    status_code=204,
    response_class=Response,
    summary="Delete a mesh and its data",
    responses=problem_responses(401, 403, 404),
)
def delete_mesh(mesh_id: str, _: WriterDep, storage: StorageDep, reads: ReadsDep) -> Response:
    record = storage.delete_mesh(mesh_id)
    if record is None:
        raise Problem("mesh-not-found", f"no mesh has id {mesh_id!r}")
    reads.evict(record.id)
    return Response(status_code=204)


def _header_safe(text: str) -> str:
    return "".join(
        ch if ch.isascii() and ch.isprintable() and ch not in '"\\' else "_" for ch in text
    )
