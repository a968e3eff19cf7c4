"""names and metadata on uploads, jobs and batches; models.sha256 for archive reuse; indexes for deletes

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-24

Every upload (models, rigs, videos), job (a batch trial is a job) and batch gets a free JSON
``metadata`` object; rigs, videos, jobs and batches a ``name`` (models already have one).
``models.sha256`` (of the XML as uploaded) finds an identical model of the same lab; existing
models are hashed here, so one uploaded again before this migration is found too.
"""
import hashlib
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = '0004'
down_revision: str | None = '0003'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

NAMED = ('rigs', 'videos', 'jobs', 'batches')
WITH_METADATA = ('models', *NAMED)


def upgrade() -> None:
    for table in WITH_METADATA:
        with op.batch_alter_table(table, schema=None) as batch_op:
            if table in NAMED:
                batch_op.add_column(sa.Column('name', sa.String(length=200), nullable=True))
            batch_op.add_column(sa.Column('metadata', sa.JSON(), nullable=True))
    with op.batch_alter_table('models', schema=None) as batch_op:
        batch_op.add_column(sa.Column('sha256', sa.String(length=64), nullable=True))
        batch_op.create_index('ix_models_lab_id_sha256', ['lab_id', 'sha256'], unique=False)
    # Deleting an upload looks up the jobs that name it.
    op.create_index('ix_jobs_model_id', 'jobs', ['model_id'], unique=False)
    op.create_index('ix_jobs_rig_id', 'jobs', ['rig_id'], unique=False)
    op.create_index('ix_job_videos_video_id', 'job_videos', ['video_id'], unique=False)
    models = sa.table('models', sa.column('id', sa.Integer), sa.column('xml', sa.Text),
                      sa.column('sha256', sa.String))
    connection = op.get_bind()
    for id_, xml in connection.execute(sa.select(models.c.id, models.c.xml)).all():
        digest = hashlib.sha256(xml.encode()).hexdigest()
        connection.execute(models.update().where(models.c.id == id_).values(sha256=digest))


def downgrade() -> None:
    op.drop_index('ix_job_videos_video_id', table_name='job_videos')
    op.drop_index('ix_jobs_rig_id', table_name='jobs')
    op.drop_index('ix_jobs_model_id', table_name='jobs')
    with op.batch_alter_table('models', schema=None) as batch_op:
        batch_op.drop_index('ix_models_lab_id_sha256')
        batch_op.drop_column('sha256')
    for table in reversed(WITH_METADATA):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.drop_column('metadata')
            if table in NAMED:
                batch_op.drop_column('name')
