"""Builds taken from the queue by `qem worker` processes: a heartbeat per build, so a
worker killed mid-build is noticed and its build taken up by another.

Revision ID: 0002
Revises: 0001
"""

from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.execute("ALTER TABLE meshes ADD COLUMN heartbeat_at DOUBLE PRECISION")
    # The queue: the oldest queued record first (server/storage/postgres.py, claim_next).
    op.execute("CREATE INDEX meshes_queue ON meshes (created_at, id) WHERE status = 'queued'")


def downgrade() -> None:
    op.execute("DROP INDEX meshes_queue")
    op.execute("ALTER TABLE meshes DROP COLUMN heartbeat_at")
