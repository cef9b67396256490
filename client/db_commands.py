"""``qem db upgrade``: create or migrate the PostgreSQL schema of the scaled deployment.

    QEM_DATABASE_URL=postgresql://qem:secret@db:5432/qem qem db upgrade

Run it once before the first ``qem serve`` on a new database, and after installing a
qem-lod whose schema is newer: servers refuse to start on a schema that is not theirs
(server/migrations). The embedded SQLite store needs nothing of the kind.
"""

from __future__ import annotations

import argparse

from .console import EXIT_OK, EXIT_UNREACHABLE, EXIT_USAGE, CliError, print_json

__all__ = ["add_db", "check_database"]


def add_db(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("db", help="the PostgreSQL schema (QEM_DATABASE_URL)")
    commands = parser.add_subparsers(dest="db_command", required=True, metavar="ACTION")
    upgrade = commands.add_parser("upgrade", help="create or migrate the schema to this version's")
    upgrade.add_argument(
        "--database-url", help="postgresql://user:pass@host:port/db (default $QEM_DATABASE_URL)"
    )
    upgrade.add_argument("--json", action="store_true", help="print the result as JSON")
    upgrade.set_defaults(run=cmd_db_upgrade)


def _database_url(given: str | None) -> str:
    from pydantic import ValidationError

    from server.settings import Settings

    try:
        settings = Settings(database_url=given) if given else Settings()
    except ValidationError as exc:
        raise CliError("; ".join(error["msg"] for error in exc.errors()), EXIT_USAGE) from None
    if not settings.database_url:
        raise CliError(
            "QEM_DATABASE_URL is not set (nor --database-url): the embedded SQLite store "
            "makes its own schema",
            EXIT_USAGE,
        )
    return settings.database_url


def cmd_db_upgrade(args: argparse.Namespace) -> int:
    import psycopg

    from server.migrations import upgrade

    url = _database_url(args.database_url)
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


def check_database(settings) -> None:
    """Before serving: a PostgreSQL database must answer and hold this version's schema;
    else a CliError saying what to do."""
    if not settings.database_url:
        return
    from server.storage import StorageUnavailable
    from server.storage.postgres import SchemaMismatch, check_schema

    try:
        check_schema(settings.database_url)
    except SchemaMismatch as exc:
        raise CliError(str(exc), EXIT_USAGE) from None
    except StorageUnavailable as exc:
        raise CliError(str(exc), EXIT_UNREACHABLE) from None
