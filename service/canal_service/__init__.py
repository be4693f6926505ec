"""Canal REST service: skills, demonstrations, fitted canals and reproductions over HTTP.

``create_app(settings)`` builds the FastAPI app; ``python -m canal_service`` serves it.
"""

from __future__ import annotations

__version__ = "0.2.0"

__all__ = ["__version__"]
