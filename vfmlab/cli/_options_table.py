"""The option table of docs/decisions/0004-cli-and-console.md, read from the commands themselves.

``python -m vfmlab.cli._options_table`` prints it (Markdown); tests/test_cli_grammar.py checks that the
table in the decision file is the one the CLI has.
"""

from __future__ import annotations

import click

from vfmlab.cli import COMMANDS, cli

HEADER = "| command | option | value | default | meaning |"


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ").strip()


def _default(option: click.Option) -> str:
    if option.required:
        return "required"
    if option.is_flag and option.secondary_opts:
        return option.opts[-1] if option.default else option.secondary_opts[-1]
    value = option.default
    if option.is_flag or value is None or value is False or value == () or type(value).__name__ == "Sentinel":
        return ""
    return str(value)


def option_rows() -> list[tuple[str, str, str, str, str]]:
    """(command, flags, value, default, meaning) of every option of every command, in --help order."""
    ctx = click.Context(cli)
    rows = []
    for name in COMMANDS:
        command = cli.get_command(ctx, name)
        for p in command.params:
            if not isinstance(p, click.Option) or p.name == "help":
                continue
            flags = ", ".join(f"`{f}`" for f in sorted(p.opts, key=len) + list(p.secondary_opts))
            value = "flag" if p.is_flag else p.make_metavar(click.Context(command))
            meaning = ("(hidden: accepted for old scripts) " if p.hidden else "") + (p.help or "")
            rows.append((f"`{name}`", flags, _cell(value), _cell(_default(p)), _cell(meaning)))
    return rows


def markdown() -> str:
    lines = [HEADER, "|---|---|---|---|---|"]
    lines += ["| " + " | ".join(row) + " |" for row in option_rows()]
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    print(markdown())
