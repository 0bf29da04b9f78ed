"""Scene files (docs/scene.md): read, validated against
exabricks/data/scene.schema.json, and their mistakes reported as one line naming
the file and the key path (`SceneFile`, `read_scene_file`)."""

from __future__ import annotations

from pathlib import Path

from ..util.errors import ExabricksError, quoted, shortened
from ..util.jsonfile import not_regular

MAX_SCHEMA_ERRORS = 500


def scene_schema() -> dict:
    """The JSON Schema of scene files: exabricks/data/scene.schema.json, with the
    node of every declared scalar option (exabricks.scene.options, `Option.target`)
    put at its key path."""
    import json
    from importlib import resources

    from .options import SCENE_OPTIONS

    schema = json.loads((resources.files("exabricks") / "data" / "scene.schema.json")
                        .read_text("utf-8"))
    for option in SCENE_OPTIONS:
        if option.target:
            properties = schema["properties"]
            for key in option.key[:-1]:
                holder = properties[key]
                if "$ref" in holder:
                    holder = schema["$defs"][holder["$ref"].rpartition("/")[2]]
                properties = holder["properties"]
            properties[option.key[-1]] = option.schema()
    return schema


def _key_path(path) -> str:
    """``volumes[1].transfer_function`` from ("volumes", 1, "transfer_function")."""
    out = ""
    for key in path:
        if isinstance(key, int):
            out += f"[{key}]"
        elif key.isidentifier():  # shortened: a key of megabytes is not echoed whole
            key = shortened(key)
            out += f".{key}" if out else key
        else:
            out += f"[{shown(key)}]"
    return out


def shown(value, most: int = 60) -> str:
    """A short JSON rendering of `value` for messages (util.errors.shortened)."""
    import json

    try:
        text = json.dumps(value)
    except RecursionError:
        return "a deeply nested value"
    return shortened(text, most)


def key_at(name: str | None, path) -> str:
    """Where a value sits: ``scene.json: volumes[1].field`` (just the file for the root)."""
    keys = _key_path(path)
    return f"{name}: {keys}" if keys else str(name)


def _finite_number(checker, value) -> bool:
    import math

    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:  # an integer beyond float range
        return False


def _schema_error_message(error, schema: dict, doc, name: str) -> str:
    """One line for one jsonschema error: `PATH: KEY.PATH: expected ... (found X)`."""
    resolve = lambda node: schema["$defs"][node["$ref"].rsplit("/", 1)[1]]
    # Walk the schema along the error's schema path, noting the instance depth of
    # every node; '$ref' steps are implicit in jsonschema's paths.
    nodes, node, depth = [], schema, 0
    keys = list(error.absolute_schema_path)
    i = 0
    while True:
        nodes.append((depth, node))
        while keys[i:] and keys[i] not in node and "$ref" in node:
            node = resolve(node)
            nodes.append((depth, node))
        if i >= len(keys) - 1:
            break
        key = keys[i]
        if key == "properties":
            node, depth, i = node[key][keys[i + 1]], depth + 1, i + 2
        elif key in ("items", "additionalProperties"):
            node, depth, i = node[key], depth + 1, i + 1
        elif key in ("allOf", "anyOf", "oneOf"):
            node, i = node[key][keys[i + 1]], i + 2
        else:  # if / then / else / not
            node, i = node[key], i + 1
    path = list(error.absolute_path)
    instance = error.instance
    if error.validator == "additionalProperties":
        known = list(node.get("properties", {}))
        extra = next(k for k in instance if k not in known)
        return f"{key_at(name, path + [extra])}: unknown key (expected one of: {', '.join(known)})"
    if error.validator == "required":
        missing = next(k for k in node["required"] if k not in instance)
        prop = node["properties"][missing]
        while "description" not in prop and "$ref" in prop:
            prop = resolve(prop)
        return f"{key_at(name, path + [missing])}: expected {prop['description']} (missing)"
    described = [(d, n) for d, n in nodes if "description" in n and d <= len(path)]
    deepest = max(d for d, _ in described)
    description = next(n["description"] for d, n in described if d == deepest)
    found = doc
    for key in path[:deepest]:
        found = found[key]
    return f"{key_at(name, path[:deepest])}: expected {description} (found {shown(found)})"


def _doc_order(doc, path) -> tuple:
    """Sort key of an instance path: keys by their place in the file, items by index."""
    order, node = [], doc
    for key in path:
        order.append(list(node).index(key) if isinstance(node, dict) else key)
        node = node[key]
    return tuple(order)


def _no_duplicate_keys(pairs):
    out = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {quoted(key)}")
        out[key] = value
    return out


def read_scene_file(path) -> dict:
    """The parsed scene file `path`, validated against the scene schema; one
    ExabricksError `PATH: KEY.PATH: what was expected (found X)` for the first
    mistake in file order (docs/scene.md)."""
    from ..util.jsonfile import read_json

    return validate_scene(read_json(path, "scene file", object_pairs_hook=_no_duplicate_keys), path)


def validate_scene(doc, name) -> dict:
    """`doc` (a scene file's object, named `name` in messages) validated against the
    scene schema: one ExabricksError `NAME: KEY.PATH: ...` for the first mistake."""
    import itertools

    import jsonschema

    path = name
    schema = scene_schema()
    if isinstance(doc, dict):  # the top-level lists' limits, before their items are validated
        for key, value in doc.items():
            limit = schema["properties"].get(key, {}).get("maxItems")
            if isinstance(value, list) and limit is not None and len(value) > limit:
                raise ExabricksError(f"{key_at(str(path), (key,))}: expected "
                                     f"{schema['properties'][key]['description']} "
                                     f"(found a list of {len(value):,})")
    base = jsonschema.Draft202012Validator
    validator_class = jsonschema.validators.extend(
        base, type_checker=base.TYPE_CHECKER.redefine("number", _finite_number))
    # The first mistake in file order among the first few hundred found: a hostile
    # file may hold millions, and a list's own limits are reported before its items.
    errors = list(itertools.islice(validator_class(schema).iter_errors(doc), MAX_SCHEMA_ERRORS))
    if errors:
        priority = ("type", "additionalProperties", "required")
        first = min(errors, key=lambda e: (
            _doc_order(doc, e.absolute_path),
            priority.index(e.validator) if e.validator in priority else len(priority)))
        raise ExabricksError(_schema_error_message(first, schema, doc, str(path)))
    return doc


class SceneFile:
    """A validated scene file: its object, its name in messages and its folder
    (the base of the relative paths it holds). `SceneFile(None)` is no file; a
    dict is a scene file's object given in Python (eb.render's `scene`), named
    "scene", its relative paths relative to the working directory."""

    def __init__(self, path):
        if isinstance(path, dict):
            self.name, self.folder = "scene", Path.cwd()
            self.doc = validate_scene(_plain(path), "scene")
            return
        self.name = None if path is None else str(path)
        self.folder = None if path is None else Path(path).parent
        self.doc = {} if path is None else read_scene_file(path)

    def at(self, *path) -> str:
        return key_at(self.name, path)

    def get(self, *path, default=None):
        node = self.doc
        for key in path:
            if not isinstance(node, dict) or key not in node:
                return default
            node = node[key]
        return node

    def _file(self, value: str, what: str, *path) -> Path:
        """The regular file `value` names, relative to the scene file's folder; else
        ExabricksError naming the key path and what was expected."""
        file = self.folder / value
        problem = not_regular(file)
        if problem:
            raise ExabricksError(f"{self.at(*path)}: expected {what} (found {shown(value)}: "
                                 f"{problem}: {shortened(str(file))})")
        return file

    def camera_file(self) -> Path | None:
        value = self.doc.get("camera")
        return self._file(value, "a camera file", "camera") if isinstance(value, str) else None

    def preset_file(self, value, *path) -> Path | None:
        """The preset file a transfer-function string names (None: a built-in name)."""
        from ..picture.transfer_function import builtin_presets

        file = self.folder / value
        problem = not_regular(file)
        if problem is None:
            return file
        if value in builtin_presets():
            return None
        raise ExabricksError(
            f"{self.at(*path)}: expected a preset file, a built-in preset name or a preset object "
            f"(found {shown(value)}: {problem}: {shortened(str(file))}, nor a built-in preset: "
            f"{', '.join(builtin_presets())})")

    def mesh_file(self, i: int) -> Path:
        """The file of mesh i, relative to the scene file's folder."""
        return self._file(self.doc["meshes"][i]["path"], "a mesh file", "meshes", i, "path")

    def references(self) -> list[Path]:
        """Every file the scene names (camera, preset and mesh files), each checked to exist."""
        files = [self.camera_file()]
        for i, volume in enumerate(self.doc.get("volumes", [])):
            tf = volume.get("transfer_function")
            if isinstance(tf, str):
                files.append(self.preset_file(tf, "volumes", i, "transfer_function"))
        files += [self.mesh_file(i) for i in range(len(self.doc.get("meshes", [])))]
        return [f for f in files if f is not None]


def scene_file_references(path) -> list[Path]:
    """The files scene file `path` (or a scene object) refers to (camera file, preset
    files), resolved against its folder; ExabricksError naming the key path of a
    missing one."""
    return SceneFile(path).references()


def _plain(doc):
    """A Python scene object as JSON values (tuples as lists, numpy numbers as numbers),
    as a file holding it would read."""
    import json

    from ..util.jsonfile import json_default

    try:
        text = json.dumps(doc, default=json_default)
    except TypeError as e:
        raise ExabricksError(f"scene: {e} (a scene holds numbers, strings, lists and objects)") from None
    return json.loads(text, parse_constant=_refuse)


def _refuse(name):
    raise ExabricksError(f"scene: {name} is not a number a scene file may hold")
