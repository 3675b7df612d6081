"""The API's track."""

from fastapi import APIRouter

__all__ = ["router"]

router = APIRouter(tags=["track"])
