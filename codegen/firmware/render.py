"""Jinja2 rendering of the firmware templates: strict, deterministic, shared by every target."""

from __future__ import annotations

from functools import lru_cache

import jinja2

from codegen import __version__
from codegen.paths import templates_dir


@lru_cache(maxsize=1)
def environment() -> jinja2.Environment:
    """One Environment over templates/: undefined names are errors, block tags leave no blank lines."""
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(templates_dir())),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        autoescape=False,
    )
    env.globals["version"] = __version__
    env.filters["hex"] = lambda value, width=2: f"0x{int(value):0{width}X}"
    return env


def render(template: str, **context: object) -> str:
    """Render `template` (a path under templates/, e.g. "avr/player.c.j2") with `context`."""
    return environment().get_template(template).render(**context)
