"""Persistence: tables, the database handle and repository functions."""

from .db import Database
from .models import (
    Base,
    Correction,
    Demonstration,
    ModelLineage,
    ModelVersion,
    SceneRow,
    Skill,
    StoredReproduction,
)

__all__ = ["Base", "Correction", "Database", "Demonstration", "ModelLineage", "ModelVersion",
           "SceneRow", "Skill", "StoredReproduction"]
