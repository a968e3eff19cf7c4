"""Labs and their API keys: a key is shown once, only its sha256 is stored."""

from __future__ import annotations

import hashlib
import secrets

from sqlalchemy import select
from sqlalchemy.orm import Session

from service.models import Lab


def hash_key(key: str) -> str:
    """sha256 hex of a key: keys are 256-bit random, so a plain hash is enough (no salt needed
    against guessing, and lookup stays one indexed equality)."""
    return hashlib.sha256(key.encode()).hexdigest()


def create_lab(session: Session, name: str) -> tuple[Lab, str]:
    """A new lab and its API key (the only time the key exists in clear)."""
    if not name.strip():
        raise ValueError("a lab needs a name")
    key = secrets.token_urlsafe(32)
    lab = Lab(name=name.strip(), key_hash=hash_key(key))
    session.add(lab)
    session.flush()
    return lab, key


def lab_for_key(session: Session, key: str) -> Lab | None:
    return session.scalars(select(Lab).where(Lab.key_hash == hash_key(key))).first()


def all_labs(session: Session) -> list[Lab]:
    return list(session.scalars(select(Lab).order_by(Lab.id)))


def revoke_key(session: Session, lab_id: int) -> Lab:
    """Forget the lab's key (its hash): no key opens the lab until :func:`rotate_key`."""
    lab = _lab(session, lab_id)
    lab.key_hash = None
    return lab


def rotate_key(session: Session, lab_id: int) -> tuple[Lab, str]:
    """A new key for the lab (shown once); the old one stops working."""
    lab = _lab(session, lab_id)
    key = secrets.token_urlsafe(32)
    lab.key_hash = hash_key(key)
    return lab, key


def _lab(session: Session, lab_id: int) -> Lab:
    lab = session.get(Lab, lab_id)
    if lab is None:
        raise ValueError(f"there is no lab {lab_id} in this database (mocap admin list-labs)")
    return lab
