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
