"""The meshes table: one record per upload and the state of its build.

The same columns as the SQLite store (server/storage/sqlite.py), ``options`` and ``bbox``
as JSON text, so that server/storage/sql.py's statements serve both.

Revision ID: 0001
Revises:
"""

from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.execute(
        """
        CREATE TABLE meshes (
            id           TEXT PRIMARY KEY,
            name         TEXT NOT NULL,
            upload_key   TEXT NOT NULL,
            upload_bytes BIGINT NOT NULL,
            status       TEXT NOT NULL
                         CHECK (status IN ('queued', 'building', 'ready', 'failed')),
            progress     DOUBLE PRECISION NOT NULL DEFAULT 0,
            options      TEXT NOT NULL DEFAULT '{}',
            attempts     INTEGER NOT NULL DEFAULT 0,
            claim        TEXT,
            qpm_key      TEXT,
            n_vertices   BIGINT,
            n_faces      BIGINT,
            n_base       BIGINT,
            bbox         TEXT,
            error        TEXT,
            created_at   DOUBLE PRECISION NOT NULL,
            updated_at   DOUBLE PRECISION NOT NULL
        )
        """
    )
    op.execute("CREATE INDEX meshes_status ON meshes (status)")


def downgrade() -> None:
    op.execute("DROP TABLE meshes")
