"""Alias of :mod:`arcsem.share` (stage-1 sharing lives there; this name was in the first design)."""
from __future__ import annotations

from ..share import (
    STAGE1_KEYS,
    cache_root,
    ensure_stage1,
    is_done,
    mark_done,
    stage1_dir,
    stage1_key,
    stage1_lock,
    stage1_result,
)

__all__ = ["STAGE1_KEYS", "cache_root", "ensure_stage1", "is_done", "mark_done", "stage1_dir", "stage1_key",
           "stage1_lock", "stage1_result"]
