"""The scaled deployment's commands: ``qem db upgrade`` and ``qem worker``.

    QEM_DATABASE_URL=postgresql://qem:secret@db:5432/qem qem db upgrade
    QEM_DATABASE_URL=... QEM_BLOB_URL=s3://bucket/prefix qem worker --slots 2

``qem db upgrade`` creates or migrates the PostgreSQL schema: run it once before the
first ``qem serve`` on a new database, and after installing a qem-lod whose schema is
newer (servers and workers refuse a schema that is not theirs, server/migrations).
``qem worker`` takes builds from the database's queue (server/jobs/postgres.py) on this
machine until SIGTERM or Ctrl-C, which hand its running builds back to the queue. The
embedded deployment (SQLite, builds inside ``qem serve``) needs neither.
"""

from __future__ import annotations

import argparse
from typing import Any

from .console import EXIT_OK, EXIT_UNREACHABLE, EXIT_USAGE, CliError, print_json

__all__ = ["add_db", "add_worker", "check_storage"]


def add_db(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("db", help="the PostgreSQL schema (QEM_DATABASE_URL)")
    commands = parser.add_subparsers(dest="db_command", required=True, metavar="ACTION")
    upgrade = commands.add_parser("upgrade", help="create or migrate the schema to this version's")
    upgrade.add_argument(
        "--database-url", help="postgresql://user:pass@host:port/db (default $QEM_DATABASE_URL)"
    )
    upgrade.add_argument("--json", action="store_true", help="print the result as JSON")
    upgrade.set_defaults(run=cmd_db_upgrade)


def add_worker(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "worker", help="run builds from the PostgreSQL queue (QEM_DATABASE_URL)"
    )
    parser.add_argument(
        "--slots", type=int, default=None,
        help="builds at once, each in a process of its own (default $QEM_WORKERS)",
    )  # fmt: skip
    parser.add_argument("--log-level", default="info", choices=["debug", "info", "warning"])
    parser.set_defaults(run=cmd_worker)


def cmd_worker(args: argparse.Namespace) -> int:
    from server.jobs.postgres import WorkerPool
    from server.request_log import configure_logging
    from server.storage import open_storage

    settings = _database_settings(
        {"workers": args.slots} if args.slots is not None else {},
        "qem worker takes builds from the PostgreSQL queue: set QEM_DATABASE_URL (the "
        "embedded deployment builds inside qem serve)",
    )
    configure_logging(args.log_level, settings.log_format)
    check_storage(settings)
    storage = open_storage(settings)
    try:
        WorkerPool(settings, storage, settings.workers).run_until_signalled()
    finally:
        storage.close()
    return EXIT_OK


def _database_settings(overrides: dict[str, Any], without: str):
    """The settings from the environment with `overrides`, which must name a database;
    else a CliError (`without`: why one is needed)."""
    from pydantic import ValidationError

    from server.settings import Settings

    try:
        settings = Settings(**overrides)
    except ValidationError as exc:
        raise CliError("; ".join(error["msg"] for error in exc.errors()), EXIT_USAGE) from None
    if not settings.database_url:
        raise CliError(without, EXIT_USAGE)
    return settings


def cmd_db_upgrade(args: argparse.Namespace) -> int:
    import psycopg

    from server.migrations import upgrade

    url = _database_settings(
        {"database_url": args.database_url} if args.database_url else {},
        "QEM_DATABASE_URL is not set (nor --database-url): the embedded SQLite store makes "
        "its own schema",
    ).database_url
    try:
        before, after = upgrade(url)
    except (psycopg.OperationalError, OSError) as exc:
        raise CliError(f"the database does not answer: {exc}", EXIT_UNREACHABLE) from None
    if args.json:
        print_json({"before": before, "after": after})
    elif before == after:
        print(f"the schema is at revision {after}, this version's: nothing to do")
    else:
        print(f"migrated the schema from {before or 'nothing'} to revision {after}")
    return EXIT_OK


def check_storage(settings) -> None:
    """Before serving or working: a PostgreSQL database must answer and hold this
    version's schema, an S3 store must take a write; else a CliError saying what is
    wrong (not a traceback from the server's start)."""
    from server.storage import StorageUnavailable

    try:
        if settings.database_url:
            from server.storage.postgres import SchemaMismatch, check_schema

            try:
                check_schema(settings.database_url)
            except SchemaMismatch as exc:
                raise CliError(str(exc), EXIT_USAGE) from None
        if settings.blob_url:
            from server.storage.s3 import S3BlobStore

            S3BlobStore.from_settings(settings).ping()
    except StorageUnavailable as exc:
        raise CliError(str(exc), EXIT_UNREACHABLE) from None
