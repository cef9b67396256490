"""The ``qem`` command.

    qem build IN -o OUT.qpm        simplify once, save the progressive mesh (progress bar)
    qem lod FILE.qpm -n N -o OUT   one level as PLY, OBJ, GLB or msgpack
    qem simplify IN -n N -o OUT    build and extract in one go
    qem info FILE.qpm              counts, error curve, sizes
    qem serve [--host H] [--port P] [--data-dir D] [--demo]    run the service
    qem upload IN                  upload a mesh, show upload and build progress, print id
    qem get ID -n N -o OUT         fetch the mesh at N vertices (format from OUT's suffix)
    qem ls                         list the server's meshes
    qem rm ID...                   delete meshes
    qem export ID|FILE.qpm DIR     a static export: base, stream, frame index, manifest, viewer
    qem db upgrade                 create or migrate the PostgreSQL schema (QEM_DATABASE_URL)
    qem worker [--slots N]         run builds from the PostgreSQL queue until SIGTERM

Commands against a server take ``--server URL`` (default $QEM_SERVER, else
http://127.0.0.1:8000) and read a write token from $QEM_TOKEN; ``--json`` prints
machine-readable output on stdout. Each subcommand is one ``cmd_*`` function registered by
one ``add_*`` function in `SUBCOMMANDS`.

Exit status: 0 success, 1 the server refused the request or the build failed, 2 bad usage,
3 the server cannot be reached, 4 timed out, 130 interrupted, 141 the output's reader
went away (a closed pipe, as ``qem ls | head -1``).
"""

from __future__ import annotations

import argparse
import ipaddress
import logging
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .console import (
    EXIT_BROKEN_PIPE,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_TIMEOUT,
    EXIT_UNREACHABLE,
    EXIT_USAGE,
    OUTPUT_FORMATS,
    Bar,
    CliError,
    format_of,
    note,
    parse_option_pairs,
    print_json,
    write_atomically,
)
from .export import add_export
from .http import (
    DEFAULT_SERVER,
    QemClient,
    QemClientError,
    QemConnectionError,
    QemHTTPError,
    QemTimeoutError,
)
from .local_commands import add_build, add_info, add_lod, add_simplify
from .scale_commands import add_db, add_worker, check_storage

__all__ = ["SUBCOMMANDS", "build_parser", "main"]

# The GLB carries spot's texture (an OBJ upload cannot), so the viewer shows it textured.
_DEMO_MESHES = ("server/demo/spot.glb", "server/demo/spot.obj")

log = logging.getLogger("qem")


def _port(text: str) -> int:
    """An argparse type: a TCP port, 0..65535 (0: any free one; uvicorn raised
    OverflowError past 65535)."""
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port (0..65535)")
    return port


def _seconds(text: str) -> float:
    """An argparse type: a positive, finite number of seconds (nan waited forever)."""
    try:
        seconds = float(text)
    except ValueError:
        seconds = float("nan")
    if not 0.0 < seconds < float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r} is not a positive number of seconds")
    return seconds


def _client(args: argparse.Namespace) -> QemClient:
    try:
        return QemClient(args.server, token=os.environ.get("QEM_TOKEN") or None)
    except QemClientError as exc:  # a malformed --server / $QEM_SERVER
        raise CliError(str(exc), EXIT_USAGE) from None


# -- serve -----------------------------------------------------------------------------


def add_serve(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "serve",
        help="run the HTTP service",
        description="Run the qem-lod service (settings also from QEM_* variables).",
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on")
    parser.add_argument("--port", type=_port, default=8000, help="port to listen on")
    parser.add_argument("--data-dir", type=Path, help="storage folder (QEM_DATA_DIR)")
    parser.add_argument("--workers", type=int, help="build worker processes (QEM_WORKERS)")
    parser.add_argument(
        "--demo",
        action="store_true",
        help="upload the demo mesh (spot) on start when the storage holds no mesh",
    )
    parser.add_argument(
        "--allow-anonymous-writes",
        action="store_true",
        help="listen on an address other than loopback without write tokens "
        "(QEM_ALLOW_ANONYMOUS_WRITES); else set QEM_TOKENS",
    )
    parser.add_argument(
        "--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"]
    )
    parser.add_argument(
        "--log-format", choices=["text", "json"],
        help="json: one object a line, for a log collector (QEM_LOG_FORMAT; default text)",
    )  # fmt: skip
    parser.set_defaults(run=cmd_serve)


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:  # a host name: it may resolve to anything
        return False


def _find_demo_mesh() -> Path | None:
    root = Path(__file__).resolve().parents[1]
    for candidate in _DEMO_MESHES:
        if (root / candidate).is_file():
            return root / candidate
    return None


def cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn
    from pydantic import ValidationError

    from server.app import create_app
    from server.request_log import configure_logging
    from server.settings import Settings

    configure_logging(args.log_level, args.log_format or "text")
    overrides: dict[str, Any] = {}
    if args.data_dir is not None:
        overrides["data_dir"] = args.data_dir
    if args.workers is not None:
        overrides["workers"] = args.workers
    if args.allow_anonymous_writes:
        overrides["allow_anonymous_writes"] = True
    if args.log_format is not None:
        overrides["log_format"] = args.log_format
    if args.demo:
        demo = _find_demo_mesh()
        if demo is None:
            log.warning(
                "no demo mesh found (looked for %s); starting without it",
                " and ".join(_DEMO_MESHES),
            )
        else:
            overrides["demo_mesh"] = demo
    try:
        settings = Settings(**overrides)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in error['loc'])}: {error['msg']}" for error in exc.errors()
        )
        raise CliError(f"invalid settings: {problems}", EXIT_USAGE) from None
    configure_logging(args.log_level, settings.log_format)
    check_storage(settings)
    if not settings.tokens and not settings.allow_anonymous_writes and not _is_loopback(args.host):
        raise CliError(
            f"--host {args.host} is reachable from other machines, and without write tokens "
            "anyone there could upload and delete meshes: set QEM_TOKENS (comma-separated, "
            "16+ characters each), or pass --allow-anonymous-writes "
            "(QEM_ALLOW_ANONYMOUS_WRITES=true) on a network you trust",
            EXIT_USAGE,
        )
    uvicorn.run(
        create_app(settings),
        host=args.host,
        port=args.port,
        log_level=args.log_level,
        log_config=None,  # uvicorn's lines go through configure_logging's handler
        timeout_graceful_shutdown=5,
    )
    return EXIT_OK


# -- commands against a server ------------------------------------------------------------


def _remote_parent() -> argparse.ArgumentParser:
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument(
        "--server",
        default=os.environ.get("QEM_SERVER") or DEFAULT_SERVER,
        help="server URL (default $QEM_SERVER or %(default)s)",
    )
    parent.add_argument("--json", action="store_true", help="machine-readable output")
    return parent


def add_upload(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "upload",
        parents=[_remote_parent()],
        help="upload a mesh and wait until built",
    )
    parser.add_argument("input", type=Path, help="mesh file (PLY, OBJ, STL, OFF, GLB)")
    parser.add_argument("--name", help="file name to record (default: the input's)")
    parser.add_argument(
        "-O",
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="build option, e.g. -O weighting=volume (repeatable)",
    )
    parser.add_argument("--no-wait", action="store_true", help="return once uploaded")
    parser.add_argument("--timeout", type=_seconds, help="give up waiting after this many s")
    parser.set_defaults(run=cmd_upload)


def cmd_upload(args: argparse.Namespace) -> int:
    if not args.input.is_file():
        what = "a directory, not a mesh file" if args.input.is_dir() else "no such file"
        raise CliError(f"{args.input}: {what}", EXIT_USAGE)
    options = parse_option_pairs(args.option)
    show = not args.json
    with _client(args) as qem:
        bar = Bar("upload", show)
        try:
            mesh_id = qem.upload(
                args.input,
                name=args.name,
                options=options,
                progress=lambda sent, total: bar.show(sent / total if total else 1.0),
            )
        finally:
            bar.done()  # an error's message then starts a line of its own
        if show:
            note(f"uploaded {args.input} as {mesh_id}")
        if args.no_wait:
            info = qem.info(mesh_id)
        else:
            build = Bar("build", show)
            try:
                info = qem.wait_ready(
                    mesh_id,
                    timeout=args.timeout,
                    progress=lambda info: build.show(info["progress"], info["status"]),
                )
            finally:
                build.done()
            if show:
                note(
                    f"ready: {info['vertices']} vertices, {info['faces']} faces, "
                    f"base mesh {info['min_vertices']} vertices"
                )
    if args.json:
        print_json(info)
    else:
        print(mesh_id)
    return EXIT_OK


def add_get(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "get",
        parents=[_remote_parent()],
        help="fetch a mesh at a vertex count",
    )
    parser.add_argument("id", help="mesh id")
    parser.add_argument("-n", "--vertices", type=int, help="vertex count (default: full)")
    parser.add_argument(
        "-o",
        "--output",
        required=True,
        help="output file; its suffix gives the format (.ply .obj .glb .msgpack); - = stdout",
    )
    parser.add_argument("--format", choices=sorted(set(OUTPUT_FORMATS.values())))
    parser.set_defaults(run=cmd_get)


def cmd_get(args: argparse.Namespace) -> int:
    if args.vertices is not None and args.vertices < 1:
        raise CliError(f"-n {args.vertices}: the vertex count must be at least 1", EXIT_USAGE)
    to_stdout = args.output == "-"
    fmt = format_of(args.output, args.format)
    with _client(args) as qem:
        lod = qem.fetch_lod(args.id, args.vertices, fmt)
    assert lod is not None
    write_atomically(args.output, lod.content)
    summary = {
        "id": args.id,
        "path": args.output,
        "format": fmt,
        "asked": args.vertices,
        "vertices": lod.n_vertices,
        "faces": lod.n_faces,
        "bytes": len(lod.content),
        "error": lod.error,
    }
    if args.json and not to_stdout:
        print_json(summary)
    else:
        # As `qem lod`: the server clamps the count into the mesh's levels.
        asked = args.vertices
        clamped = "" if asked is None or asked == lod.n_vertices else f" (asked {asked})"
        note(
            f"wrote {args.output}: {lod.n_vertices} vertices{clamped}, {lod.n_faces} faces "
            f"({len(lod.content)} bytes, {fmt})"
        )
    return EXIT_OK


def add_ls(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("ls", parents=[_remote_parent()], help="list meshes")
    parser.set_defaults(run=cmd_ls)


def cmd_ls(args: argparse.Namespace) -> int:
    with _client(args) as qem:
        meshes = qem.list()
    if args.json:
        print_json(meshes)
        return EXIT_OK
    if not meshes:
        note("no meshes on this server")
        return EXIT_OK
    rows = [("ID", "STATUS", "VERTICES", "FACES", "BASE", "NAME")]
    for mesh in meshes:
        status = mesh["status"]
        if status == "building":
            status = f"building {mesh['progress']:.0%}"
        rows.append(
            (
                mesh["id"],
                status,
                str(mesh["vertices"] or "-"),
                str(mesh["faces"] or "-"),
                str(mesh["min_vertices"] or "-"),
                mesh["name"],
            )
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]) - 1)]
    for row in rows:
        print(
            "  ".join(cell.ljust(width) for cell, width in zip(row[:-1], widths, strict=True))
            + "  "
            + row[-1]
        )
    return EXIT_OK


def add_rm(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("rm", parents=[_remote_parent()], help="delete meshes")
    parser.add_argument("ids", nargs="+", metavar="ID", help="mesh id")
    parser.set_defaults(run=cmd_rm)


def cmd_rm(args: argparse.Namespace) -> int:
    deleted = []
    with _client(args) as qem:
        for mesh_id in args.ids:
            qem.delete(mesh_id)
            deleted.append(mesh_id)
            if not args.json:
                note(f"deleted {mesh_id}")
    if args.json:
        print_json({"deleted": deleted})
    return EXIT_OK


# -- entry point -----------------------------------------------------------------------------

SUBCOMMANDS: list[Callable[[argparse._SubParsersAction], None]] = [
    add_build,
    add_lod,
    add_simplify,
    add_info,
    add_serve,
    add_upload,
    add_get,
    add_ls,
    add_rm,
    lambda subparsers: add_export(subparsers, _remote_parent),
    add_db,
    add_worker,
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="qem",
        description="Progressive meshes: serve them, upload to a server, fetch any level.",
        epilog="exit status: 0 ok, 1 refused or failed, 2 usage, 3 server unreachable, "
        "4 timed out, 130 interrupted, 141 output pipe closed",
    )
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in SUBCOMMANDS:
        add(subparsers)
    return parser


# The exit status of each error a command may end with, the first class that matches
# (QemTimeoutError before the QemConnectionError it is, and both before QemClientError).
_EXIT_STATUS: tuple[tuple[type[Exception], int], ...] = (
    (QemTimeoutError, EXIT_TIMEOUT),
    (QemConnectionError, EXIT_UNREACHABLE),
    (TimeoutError, EXIT_TIMEOUT),
    (QemClientError, EXIT_FAILED),  # QemHTTPError, QemBuildFailed and the rest
)


def main(argv: list[str] | None = None) -> int:
    """Run the ``qem`` command; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except CliError as exc:
        note(f"qem {args.command}: {exc}")
        return exc.status
    except (QemClientError, TimeoutError) as exc:
        message = _describe_problem(exc) if isinstance(exc, QemHTTPError) else str(exc)
        note(f"qem {args.command}: {message}")
        return next(status for kind, status in _EXIT_STATUS if isinstance(exc, kind))
    except KeyboardInterrupt:
        note("interrupted")
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # The reader is gone: point stdout at /dev/null so that the flush at exit does not
        # raise again, and end as a process killed by SIGPIPE would.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


def _describe_problem(exc: QemHTTPError) -> str:
    hints = {
        401: " (set QEM_TOKEN to a write token of this server)",
        403: " (QEM_TOKEN is not accepted by this server)",
    }
    return f"{exc.title or 'error'} ({exc.status}): {exc.detail}{hints.get(exc.status, '')}"


if __name__ == "__main__":
    sys.exit(main())
