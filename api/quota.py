"""Quotas of the store: how much the service keeps, so that a client cannot fill the disk.

Identifications store their record (up to ``TUNER_MAX_IDENTIFY_BODY_BYTES`` each). A new one is
refused with 507 (Insufficient Storage), before any work is done, when the store already holds
``TUNER_MAX_IDENTIFICATIONS`` of them or when its record would take the samples of all stored
records past ``TUNER_MAX_IDENTIFICATION_SAMPLES``. Nothing is deleted on its own: the operator
raises the limits or removes old rows.
"""

from __future__ import annotations

from fastapi import HTTPException

from .settings import Settings
from .store import Store

__all__ = ["INSUFFICIENT_STORAGE", "check_identification_quota"]

INSUFFICIENT_STORAGE = 507


def check_identification_quota(store: Store, settings: Settings, n_samples: int) -> None:
    """Raise 507 if storing one more identification of ``n_samples`` would exceed a quota."""
    count, samples = store.identification_usage()
    if count >= settings.max_identifications:
        raise HTTPException(INSUFFICIENT_STORAGE, f"the store holds {count} identifications, the most it may "
                                                  f"(TUNER_MAX_IDENTIFICATIONS={settings.max_identifications}); "
                                                  "ask the operator to remove old ones or raise the limit")
    if samples + n_samples > settings.max_identification_samples:
        raise HTTPException(INSUFFICIENT_STORAGE, f"the stored records hold {samples} samples; {n_samples} more "
                                                  "would exceed TUNER_MAX_IDENTIFICATION_SAMPLES="
                                                  f"{settings.max_identification_samples}; ask the operator to "
                                                  "remove old identifications or raise the limit")
