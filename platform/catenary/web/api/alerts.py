"""The API's alerts."""

from fastapi import APIRouter

__all__ = ["router"]

router = APIRouter(tags=["alerts"])
