"""``canal skill create|list|show|delete``."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from canal_protocol.schemas import SkillCreate

from .demos import demo_table
from .output import out, print_json, time_text
from .parsing import contract_parser, field_type
from .session import connected, options

app = typer.Typer(help="Create, list, show and delete skills.", no_args_is_help=True)


@app.command("create")
def skill_create(
    ctx: typer.Context,
    name: Annotated[str, typer.Argument(help="Letters, digits, '.', '_', '-'.")],
    dim: Annotated[int, typer.Option("--dim", min=2, max=3, help="2 or 3.")] = 3,
    description: Annotated[str, typer.Option(
        "--description", "-d", parser=contract_parser(field_type(SkillCreate, "description")))
    ] = "",
) -> None:
    """Create a skill (its dimension is fixed for life)."""
    with connected(ctx) as c:
        skill = c.create_skill(name, dim=dim, description=description)
    if options(ctx).json:
        print_json(skill)
    else:
        out.print(f"created skill [bold]{escape(skill.name)}[/bold] ({skill.dim}-D)")


@app.command("list")
def skill_list(ctx: typer.Context) -> None:
    """Every skill with its counts."""
    with connected(ctx) as c:
        skills = c.list_skills()
    if options(ctx).json:
        print_json(skills)
        return
    if not skills:
        out.print("no skills yet: canal skill create NAME")
        return
    table = Table("name", "dim", "demos", "models", "latest", "description")
    for s in skills:
        table.add_row(escape(s.name), str(s.dim), str(s.n_demonstrations), str(s.n_models),
                      "" if s.latest_model_version is None else str(s.latest_model_version),
                      escape(s.description))
    out.print(table)


@app.command("show")
def skill_show(ctx: typer.Context, name: str) -> None:
    """A skill, its demonstrations and its model versions."""
    with connected(ctx) as c:
        skill = c.get_skill(name)
        demos = c.list_demos(name)
        models = c.list_models(name)
    if options(ctx).json:
        print_json({"skill": skill, "demonstrations": demos, "models": models})
        return
    out.print(f"[bold]{escape(skill.name)}[/bold]  {skill.dim}-D  "
              f"created {time_text(skill.created_at)}")
    if skill.description:
        out.print(escape(skill.description))
    latest = skill.latest_model_version
    out.print(f"{skill.n_demonstrations} demonstrations, {skill.n_models} models"
              + (f", latest version {latest}" if latest is not None else ", not fitted yet"))
    if demos:
        out.print(demo_table(demos))
    if models:
        table = Table("version", "section", "demos", "sections", "routes", "fit s", "created",
                      title="models")
        for m in models:
            table.add_row(str(m.version), m.section_kind, str(m.n_demos), str(m.n_sections),
                          str(m.routes), f"{m.fit_seconds:.3f}", time_text(m.created_at))
        out.print(table)


@app.command("delete")
def skill_delete(
    ctx: typer.Context, name: str,
    yes: Annotated[bool, typer.Option("--yes", "-y", help="Do not ask.")] = False,
) -> None:
    """Delete a skill with all its demonstrations and models."""
    if not yes:
        typer.confirm(f"delete skill {name!r} with all its demonstrations and models?",
                      abort=True, err=True)
    with connected(ctx) as c:
        c.delete_skill(name)
    if not options(ctx).json:
        out.print(f"deleted skill {escape(name)}")
