"""The API's maintenance."""

from fastapi import APIRouter

__all__ = ["router"]

router = APIRouter(tags=["maintenance"])
