"""Persistence: tables, the database handle and repository functions."""

from .db import Database
from .models import Base, Demonstration, ModelVersion, SceneRow, Skill, StoredReproduction

__all__ = ["Base", "Database", "Demonstration", "ModelVersion", "SceneRow", "Skill",
           "StoredReproduction"]
