"""The registry of cross-section kinds: name -> :class:`~canal_core.sections.base.SectionKind`.

The five built-in kinds register themselves when :mod:`canal_core.sections` is imported; a
new kind is one module defining a ``SectionKind`` and one call to
:func:`register_section_kind`. Every consumer (fit, reproduction, envelope, mesh, tracker,
model loading) looks the kind up here instead of switching on its name.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..errors import InvalidInputError

if TYPE_CHECKING:
    from .base import SectionKind

_KINDS: dict[str, SectionKind] = {}


def register_section_kind(kind: SectionKind, *, replace: bool = False) -> SectionKind:
    """Make ``kind`` available to :func:`canal_core.fit` and to model loading by its name.

    Parameters
    ----------
    kind : SectionKind
    replace : bool
        Allow replacing a kind already registered under the same name (off by default so
        two modules cannot silently shadow each other).

    Returns
    -------
    SectionKind
        ``kind``, so a module can write ``BOX = register_section_kind(SectionKind(...))``.
    """
    if not isinstance(kind.name, str) or not kind.name:
        raise InvalidInputError(f"expected a non-empty kind name, got {kind.name!r}", field="kind")
    if kind.name in _KINDS and not replace and _KINDS[kind.name] is not kind:
        raise InvalidInputError(
            f"expected a new cross-section kind name, got {kind.name!r} which is already registered",
            field="kind",
        )
    _KINDS[kind.name] = kind
    return kind


def unregister_section_kind(name: str) -> None:
    """Remove a registered kind (for tests that register a temporary one)."""
    _KINDS.pop(name, None)


def section_kind(name: str) -> SectionKind:
    """The registered kind called ``name``; raises :class:`InvalidInputError` naming the choices."""
    try:
        return _KINDS[name]
    except (KeyError, TypeError):
        raise InvalidInputError(
            f"expected a cross-section kind among {', '.join(map(repr, _KINDS))}, got {name!r}",
            field="cross_section",
        ) from None


def section_kinds(dim: int | None = None) -> tuple[str, ...]:
    """Names of the registered kinds, in registration order.

    Parameters
    ----------
    dim : {2, 3}, optional
        Only the kinds a ``dim``-D canal's sections can have (in-plane dimension dim - 1):
        ``dim=3`` gives the choices of ``FitOptions.cross_section``.
    """
    return tuple(k.name for k in _KINDS.values() if dim is None or k.in_plane_dim == dim - 1)
