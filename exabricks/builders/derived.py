"""Fields made from others at ingest: `add_magnitude` a vector magnitude of
component fields (DESIGN.md "Fields"), `parse_expression` and `add_derived` a
field given by an expression over the others (checked here, evaluated by
numexpr), and `apply_mask` the cells where a field is 0 dropped (the body of an
embedded-boundary plotfile, whose `volFrac` is 0 there)."""

from __future__ import annotations

import ast
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from ..util.constants import AUTO_MASK_FIELD, VALUE_DTYPE
from ..util.errors import ExabricksError
from ..schema import Cells


def apply_mask(cells: Cells, field: str, *, source: str) -> Cells:
    """`cells` without those where field `field` is exactly 0 (+0 or -0); NaN is kept.

    Raises ExabricksError naming `source` when the field is missing or every cell
    would go.
    """
    if field not in cells.fields:
        raise ExabricksError(
            f"{source}: no field {field!r} for --mask (fields: {', '.join(cells.fields) or 'none'})"
        )
    keep = cells.values[cells.fields.index(field)] != 0
    if keep.all():
        return cells
    if not keep.any():
        raise ExabricksError(
            f"{source}: every cell has {field} == 0: nothing is left after masking "
            f"(--mask {field}{'; --no-mask keeps them' if field == AUTO_MASK_FIELD else ''})"
        )
    return cells.replace(
        lower_lattice=np.ascontiguousarray(cells.lower_lattice[keep]),
        level=np.ascontiguousarray(cells.level[keep]),
        values=np.ascontiguousarray(cells.values[:, keep]),
    )


def add_magnitude(cells: Cells, name: str, components: tuple[str, ...], *, source: str) -> Cells:
    """Append field `name` = sqrt(sum of squares of `components`), computed in float64.

    values: float32 (F + 1, N); the new row is last.
    """
    if name in cells.fields:
        raise ExabricksError(f"{source}: a field named {name!r} exists already")
    if not components:
        raise ExabricksError(f"{source}: magnitude {name!r} needs at least one component")
    rows = []
    for c in components:
        if c not in cells.fields:
            raise ExabricksError(
                f"{source}: no field {c!r} for magnitude {name!r} (fields: {', '.join(cells.fields)})"
            )
        rows.append(cells.values[cells.fields.index(c)].astype(np.float64))
    mag = np.sqrt(sum(r * r for r in rows)).astype(VALUE_DTYPE)
    return cells.replace(fields=(*cells.fields, name), values=np.vstack([cells.values, mag[None]]))


FUNCTIONS = {
    **dict.fromkeys(("abs", "arccos", "arccosh", "arcsin", "arcsinh", "arctan", "arctanh",
                     "ceil", "cos", "cosh", "exp", "expm1", "floor", "isfinite", "isinf",
                     "isnan", "log", "log10", "log1p", "log2", "ones_like", "round", "sign",
                     "signbit", "sin", "sinh", "sqrt", "tan", "tanh", "trunc"), 1),
    **dict.fromkeys(("arctan2", "copysign", "fmod", "hypot", "maximum", "minimum",
                     "nextafter"), 2),
    "where": 3,
}
"""The functions a derived field's expression may call, with their argument counts:
numexpr's element-wise real functions.  Its reductions (sum, prod, min, max) give one
value for all cells, and its complex and string functions no real value per cell, so
they are refused as unknown functions."""


_OPERATORS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**",
              ast.Mod: "%", ast.BitAnd: "&", ast.BitOr: "|", ast.BitXor: "^",
              ast.FloorDiv: "//", ast.LShift: "<<", ast.RShift: ">>", ast.MatMult: "@",
              ast.USub: "-", ast.UAdd: "+", ast.Invert: "~", ast.Not: "not",
              ast.Lt: "<", ast.LtE: "<=", ast.Gt: ">", ast.GtE: ">=", ast.Eq: "==",
              ast.NotEq: "!=", ast.In: "in", ast.NotIn: "not in", ast.Is: "is",
              ast.IsNot: "is not"}


# numexpr's `^` is a boolean xor and its `//` a true division: refused, as are the
# operators numexpr lacks.
_REFUSED = {"^": " (** is the power)", "//": " (use floor(a / b))", "not": " (use ~)"}


_ALLOWED = {"+", "-", "*", "/", "**", "%", "&", "|", "~", "<", "<=", ">", ">=", "==", "!="}


_QUOTED = re.compile(r"`([^`]*)`")


@dataclass(frozen=True)
class Expression:
    """A derived field NAME = TEXT, parsed and checked by `parse_expression`.

    fields: the field names the expression reads, in order of first use.
    constants: its numbers (as float64) and truth values, in order.
    program: the numexpr source that computes it: field i renamed `_v{i}`, constant j
             `_c{j}`.  numexpr gets the constants as 0-d arrays, not as literals, so
             that it folds none of them in Python: T / 0 is then inf at every cell (as
             0 / 0 is NaN) instead of a ZeroDivisionError, and no integer overflows.
    """

    name: str
    text: str
    fields: tuple[str, ...]
    constants: tuple[float | bool, ...]
    program: str

    def operands(self, rows: Iterable[np.ndarray]) -> dict[str, np.ndarray]:
        """numexpr's local_dict: `rows` (one float64 (N,) array per field) and the constants."""
        named = {f"_v{i}": row for i, row in enumerate(rows)}
        for j, c in enumerate(self.constants):
            named[f"_c{j}"] = np.array(c, np.bool_ if isinstance(c, bool) else np.float64)
        return named


def parse_expression(name: str, text: str, *, source: str) -> Expression:
    """The checked expression of derived field `name` = `text` (no field is looked at yet).

    The language is numexpr's: numbers, field names, + - * / ** %, comparisons
    (< <= > >= == !=, one per pair of operands), & | ~ on comparisons, parentheses and
    calls of FUNCTIONS.  A field whose name is not a Python identifier (x-velocity,
    gas:density) is written between backticks: `x-velocity`.  Everything else
    (attributes, indexing, strings, keywords such as lambda or if, Python's and/or/not)
    is refused.  The text is parsed with `ast` and rewritten, never evaluated by
    Python; numexpr then compiles the rewritten program on a one-cell probe, so a type
    error (& between numbers) is found here too.

    Raises ExabricksError naming `source`, the field and its expression.
    """
    where = _where(source, name, text)
    if not name:
        raise ExabricksError(f"{where}: the field needs a name")
    if "`" in name:
        raise ExabricksError(f"{where}: a field name cannot hold a backtick")
    if not text.strip():
        raise ExabricksError(f"{where}: empty expression")
    prefix = "_q"
    while prefix in text:  # placeholders that no identifier of the text can equal
        prefix += "_"
    quoted: dict[str, str] = {}

    def placeholder(match):
        if not match.group(1):
            raise ExabricksError(f"{where}: empty field name between backticks")
        return " " + quoted.setdefault(match.group(1), f"{prefix}{len(quoted)}") + " "

    body = _QUOTED.sub(placeholder, text).strip()
    if "`" in body:
        raise ExabricksError(f"{where}: unmatched backtick")
    unquote = {v: k for k, v in quoted.items()}
    fields: dict[str, str] = {}
    constants: list[float | bool] = []
    try:
        tree = ast.parse(body, mode="eval")
        program = ast.unparse(_rewrite(tree.body, fields, constants, unquote, where))
    except SyntaxError as e:
        raise ExabricksError(f"{where}: syntax error ({e.msg})") from None
    except (RecursionError, MemoryError, ValueError) as e:
        raise ExabricksError(f"{where}: cannot be parsed ({type(e).__name__}: too long, "
                             "too deeply nested or not text)") from None

    import numexpr

    expression = Expression(name=name, text=text, fields=tuple(fields),
                            constants=tuple(constants), program=program)
    probe = expression.operands(np.zeros(1) for _ in fields)
    problem = numexpr.validate(program, local_dict=probe, global_dict={})
    if problem is not None:
        raise ExabricksError(
            f"{where}: numexpr cannot evaluate it ({type(problem).__name__}: {problem}; "
            "&, |, ~ and where's condition take comparisons, the rest numbers)"
        )
    return expression


def _where(source: str, name: str, text: str) -> str:
    """The start of every message about derived field `name` = `text` (a long text cut)."""
    return f"{source}: derived field {name!r} = {text if len(text) <= 80 else text[:77] + '...'!r}"


def _rewrite(node: ast.expr, fields: dict[str, str], constants: list, unquote: dict[str, str],
             where: str):
    """`node` checked against the language of `parse_expression`, its field names
    renamed `_v{i}` (recorded in `fields`, name -> variable) and its constants `_c{j}`
    (their values appended to `constants`, numbers as floats)."""
    def again(child):
        return _rewrite(child, fields, constants, unquote, where)

    def operator(op):
        text = _OPERATORS.get(type(op), type(op).__name__)
        if text not in _ALLOWED:
            raise ExabricksError(f"{where}: operator {text!r} is not supported"
                                 f"{_REFUSED.get(text, '')}")
        return op

    if isinstance(node, ast.Name):
        field = unquote.get(node.id, node.id)
        return ast.Name(fields.setdefault(field, f"_v{len(fields)}"), ast.Load())
    if isinstance(node, ast.Constant):
        value = node.value
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                value = float(value)
            except OverflowError:
                raise ExabricksError(f"{where}: a number is too large for float64") from None
        if isinstance(value, (bool, float)):
            constants.append(value)
            return ast.Name(f"_c{len(constants) - 1}", ast.Load())
        raise ExabricksError(f"{where}: only real numbers can be constants, not {ast.unparse(node)}")
    if isinstance(node, ast.BinOp):
        return ast.BinOp(again(node.left), operator(node.op), again(node.right))
    if isinstance(node, ast.UnaryOp):
        return ast.UnaryOp(operator(node.op), again(node.operand))
    if isinstance(node, ast.Compare):
        if len(node.ops) != 1:
            raise ExabricksError(f"{where}: chained comparisons are not supported "
                                 "(write (a < b) & (b < c))")
        return ast.Compare(again(node.left), [operator(node.ops[0])], [again(node.comparators[0])])
    if isinstance(node, ast.BoolOp):
        raise ExabricksError(f"{where}: 'and' and 'or' are not supported (use & and | "
                             "between comparisons)")
    if isinstance(node, ast.Call):
        func = node.func
        if isinstance(func, ast.Attribute):
            raise ExabricksError(f"{where}: attribute access {ast.unparse(func)!r} is not allowed")
        if not isinstance(func, ast.Name):
            raise ExabricksError(f"{where}: only functions can be called, not {ast.unparse(func)!r}")
        arity = FUNCTIONS.get(func.id)
        if func.id in ("sum", "prod", "min", "max"):
            raise ExabricksError(f"{where}: {func.id} is a reduction over all cells, not one value "
                                 "per cell (maximum and minimum compare two values per cell)")
        if arity is None:
            raise ExabricksError(f"{where}: unknown function {func.id!r} "
                                 f"(functions: {', '.join(sorted(FUNCTIONS))})")
        if node.keywords or any(isinstance(a, ast.Starred) for a in node.args):
            raise ExabricksError(f"{where}: {func.id} takes plain positional arguments")
        if len(node.args) != arity:
            raise ExabricksError(f"{where}: {func.id} takes {arity} argument"
                                 f"{'s' * (arity > 1)}, not {len(node.args)}")
        return ast.Call(ast.Name(func.id, ast.Load()), [again(a) for a in node.args], [])
    if isinstance(node, ast.Attribute):
        raise ExabricksError(f"{where}: attribute access {ast.unparse(node)!r} is not allowed")
    if isinstance(node, ast.Subscript):
        raise ExabricksError(f"{where}: indexing {ast.unparse(node)!r} is not allowed")
    if isinstance(node, ast.IfExp):
        raise ExabricksError(f"{where}: 'if ... else' is not supported (use where(condition, a, b))")
    raise ExabricksError(f"{where}: {ast.unparse(node)!r} ({type(node).__name__}) is not allowed")


def derived_expressions(derive, taken: list[str], *, source: str) -> list[Expression]:
    """The parsed (NAME, EXPR) pairs or mapping `derive`; `taken`: the names that the
    magnitudes take first."""
    pairs = list(derive.items()) if isinstance(derive, Mapping) else list(derive)
    out: list[Expression] = []
    taken = list(taken)
    for pair in pairs:
        if isinstance(pair, (str, bytes)) or len(pair) != 2 \
                or not all(isinstance(p, str) for p in pair):
            raise ExabricksError(f"{source}: a derived field is a (NAME, EXPRESSION) pair of "
                                 f"strings, not {pair!r}")
        e = parse_expression(*pair, source=source)
        if e.name in taken:
            raise ExabricksError(f"{_where(source, e.name, e.text)}: a field named {e.name!r} "
                                 "exists already")
        taken.append(e.name)
        out.append(e)
    return out


def check_expression_fields(expression: Expression, known: Iterable[str], *, source: str) -> None:
    """Refuse `expression` when its name is one of the fields `known` (at that point) or it
    reads one that is not; the message lists `known`."""
    known = list(known)
    where = _where(source, expression.name, expression.text)
    if expression.name in known:
        raise ExabricksError(f"{where}: a field named {expression.name!r} exists already")
    missing = [f for f in expression.fields if f not in known]
    if missing:
        raise ExabricksError(f"{where}: unknown field {missing[0]!r} "
                             f"(fields: {', '.join(known) or 'none'})")


def add_derived(cells: Cells, expression: Expression, *, source: str) -> Cells:
    """Append field expression.name = the expression at every cell, computed in float64.

    values: float32 (F + 1, N); the new row is last.  A comparison gives 1.0 or 0.0, an
    expression that reads no field (a constant) the same value at every cell; inf and
    NaN (a division by zero, the log of a negative) are stored as they are, for
    `validate_cells`'s NaN policy to handle.
    """
    import numexpr

    check_expression_fields(expression, cells.fields, source=source)
    local = expression.operands(cells.values[cells.fields.index(f)].astype(np.float64)
                                for f in expression.fields)
    where = _where(source, expression.name, expression.text)
    try:
        result = np.asarray(numexpr.evaluate(expression.program, local_dict=local, global_dict={}))
    except Exception as e:  # parse_expression's probe passed; what is left is e.g. memory
        raise ExabricksError(f"{where}: numexpr failed ({type(e).__name__}: {e})") from e
    if result.shape not in ((), (cells.n_cells,)) or result.dtype.kind not in "biuf":
        raise ExabricksError(f"{where}: {result.dtype} of shape {result.shape}, not one real "
                             "value per cell")
    with np.errstate(over="ignore"):  # beyond float32: inf, like the readers
        row = np.broadcast_to(result.astype(np.float64), (cells.n_cells,)).astype(VALUE_DTYPE)
    return cells.replace(fields=(*cells.fields, expression.name),
                         values=np.vstack([cells.values, row[None]]))
