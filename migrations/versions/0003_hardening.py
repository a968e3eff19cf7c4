"""hardening: 64-bit videos.size_bytes, videos.announced_frames, revocable keys

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-23

videos.size_bytes was a 32-bit integer on PostgreSQL: an upload of 2 GiB (the default
limit) failed its INSERT. labs.key_hash NULL is a revoked key (`mocap admin revoke-key`).
"""
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = '0003'
down_revision: str | None = '0002'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table('videos', schema=None) as batch_op:
        batch_op.alter_column('size_bytes', existing_type=sa.Integer(), type_=sa.BigInteger(),
                              existing_nullable=False)
        batch_op.add_column(sa.Column('announced_frames', sa.Integer(), nullable=True))
    with op.batch_alter_table('labs', schema=None) as batch_op:
        batch_op.alter_column('key_hash', existing_type=sa.String(length=64), nullable=True)


def downgrade() -> None:
    # Refused while a lab's key is revoked (NULL): give it a key first (`mocap admin rotate-key`).
    with op.batch_alter_table('labs', schema=None) as batch_op:
        batch_op.alter_column('key_hash', existing_type=sa.String(length=64), nullable=False)
    with op.batch_alter_table('videos', schema=None) as batch_op:
        batch_op.drop_column('announced_frames')
        batch_op.alter_column('size_bytes', existing_type=sa.BigInteger(), type_=sa.Integer(),
                              existing_nullable=False)
