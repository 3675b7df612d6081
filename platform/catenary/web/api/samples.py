"""The API's samples."""

from fastapi import APIRouter

__all__ = ["router"]

router = APIRouter(tags=["samples"])
