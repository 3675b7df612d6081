"""The API's spans."""

from fastapi import APIRouter

__all__ = ["router"]

router = APIRouter(tags=["spans"])
