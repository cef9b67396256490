"""Schema migrations of the PostgreSQL metadata store (Alembic), run by ``qem db upgrade``.

The SQLite store of the embedded deployment creates its one table itself; PostgreSQL,
shared by replicas and workers of different versions during a rollout, changes only
through these revisions. `upgrade(url)` brings a database to the newest; `current` (the
database's) and `head` (this code's) tell a server whether it may start on it.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["current", "head", "sqlalchemy_url", "upgrade"]

_HERE = Path(__file__).resolve().parent


def _config(url: str):
    from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(_HERE))
    config.attributes["url"] = sqlalchemy_url(url)
    return config


def sqlalchemy_url(url: str) -> str:
    """``postgresql://...`` (libpq's form, QEM_DATABASE_URL) as SQLAlchemy names the
    psycopg 3 driver."""
    _, _, rest = url.partition("://")
    return f"postgresql+psycopg://{rest}"


def head() -> str:
    """The newest revision of this code."""
    from alembic.script import ScriptDirectory

    return ScriptDirectory.from_config(_config("postgresql://")).get_current_head()


def current(connection) -> str | None:
    """The database's revision (None: never migrated), read on a psycopg connection."""
    exists = connection.execute("SELECT to_regclass('alembic_version') IS NOT NULL").fetchone()
    if not exists[0]:
        return None
    row = connection.execute("SELECT version_num FROM alembic_version").fetchone()
    return row[0] if row else None


def upgrade(url: str, revision: str = "head") -> tuple[str | None, str]:
    """Bring the database at ``url`` to `revision` (the newest by default); (before,
    after)."""
    import psycopg
    from alembic import command

    with psycopg.connect(url, autocommit=True, connect_timeout=10) as connection:
        before = current(connection)
    command.upgrade(_config(url), revision)
    return before, head() if revision == "head" else revision


