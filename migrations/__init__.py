"""Alembic migrations of the catenary database (shipped as a package so installs carry them)."""
