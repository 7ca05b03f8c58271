"""Thin HTTP routes: validate, convert (:mod:`api.convert`), hand the work to the pool or the store."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from ..deps import require_api_key
from . import analyze, export, health, identify, page, tradeoff, tune, tunes

__all__ = ["api_router", "public_router"]

api_router = APIRouter(dependencies=[Depends(require_api_key)])
api_router.include_router(tune.router)
api_router.include_router(tradeoff.router)
api_router.include_router(analyze.router)
api_router.include_router(tunes.router)
api_router.include_router(export.router)
api_router.include_router(identify.router)

public_router = APIRouter()
public_router.include_router(health.router)
public_router.include_router(page.router)  # the browser page: the key is entered in it
