"""MkDocs hooks of the documentation site (mkdocs.yml): the reference tables that
are generated from the code when the site is built, so that they cannot go stale.

`<!-- render-options -->` in a page becomes the table of every render option
declared in exabricks.scene.options (SCENE_OPTIONS, then JOB_OPTIONS): its flag,
its key in a scene file, what it takes, its default and its help, as `render
--help` and the scene file's schema have them."""

from __future__ import annotations

MARKER = "<!-- render-options -->"


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _takes(option) -> str:
    if option.kind == "flag":
        return f"`{option.flag}` / `--no-{option.flag[2:]}`"
    metavar = option.metavar or {"float": "X", "int": "N", "text": "TEXT", "file": "FILE",
                                 "choice": "|".join(option.choices), "plane": "AXIS POSITION",
                                 "numbers": "A,B,...", "size": "SIZE"}[option.kind]
    return f"`{option.flag} {metavar}`" + (" (repeatable)" if option.multiple else "")


def _value(option) -> str:
    if option.kind in ("flag", "text", "file", "size"):
        return {"flag": "true or false", "text": "a string", "file": "a file", "size": "a size in bytes"}[option.kind]
    return option._expected() if option.kind != "float" or option.nargs == 1 else option.schema()["description"]


def options_table() -> str:
    from exabricks.scene.options import JOB_OPTIONS, SCENE_OPTIONS

    rows = ["| Flag | Scene-file key | Takes | Help |", "|---|---|---|---|"]
    for option in SCENE_OPTIONS:
        key = ".".join(option.key) if option.target else ""
        rows.append(f"| {_takes(option)} | {f'`{key}`' if key else ''} | {_cell(_value(option))} "
                    f"| {_cell(option.help)} |")
    rows.append("")
    rows.append("The options of a render job (how it runs, not what it draws: never in a scene file):")
    rows.append("")
    rows.append("| Flag | Takes | Help |")
    rows.append("|---|---|---|")
    for option in JOB_OPTIONS:
        rows.append(f"| {_takes(option)} | {_cell(_value(option))} | {_cell(option.help)} |")
    return "\n".join(rows)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER in markdown:
        markdown = markdown.replace(MARKER, options_table())
    return markdown
