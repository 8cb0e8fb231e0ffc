"""Haas program text: block parsing and macro expressions (no execution, no I/O).

A block is parsed into one :data:`Statement`:

* ``#100 = #1 * [2 + SIN[30]]`` -> :class:`Assign`
* ``IF [#1 GT 5] GOTO 20`` -> :class:`IfGoto`; ``IF [c] THEN #1 = 2`` -> :class:`IfThen`
* ``GOTO 20`` -> :class:`Goto`; ``WHILE [c] DO1`` / ``END1`` -> :class:`While` / :class:`EndLoop`
* ``DPRNT[...]`` -> :class:`Dprnt`; ``POPEN`` / ``PCLOS`` -> :class:`PortControl`
* anything else -> :class:`Words` (``G65 P9995 A20. H-1.``, ``T1 M06``, ``X#1``...)

Expressions follow the Fanuc macro-B family Haas uses: ``[ ]`` for grouping, ``#n`` and
``#[expr]`` variables, ``+ - * / MOD``, ``EQ NE GT GE LT LE``, ``AND OR XOR`` and the common
functions (angles in degrees). Malformed input raises :class:`~opendnc.errors.InputError`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field

from opendnc.errors import InputError
from opendnc.haas import dprnt

Lookup = Callable[[int], float | None]

# --------------------------------------------------------------------------- expressions


@dataclass(frozen=True, slots=True)
class Num:
    """A numeric literal: an ``int`` when written without a decimal point (``X100``), a
    ``float`` when written with one (``X100.``). Fanuc and Haas read the two differently (a
    dwell's P in milliseconds or seconds, an axis word in the least input increment or in
    mm): the dry run needs the written form; :func:`evaluate` gives a float either way."""

    value: float


@dataclass(frozen=True, slots=True)
class Var:
    """``#n`` or ``#[expr]``."""

    index: Expr


@dataclass(frozen=True, slots=True)
class Unary:
    """``-x`` or ``+x``."""

    op: str
    operand: Expr


@dataclass(frozen=True, slots=True)
class Binary:
    """``a op b`` for arithmetic, comparison and logic operators."""

    op: str
    left: Expr
    right: Expr


@dataclass(frozen=True, slots=True)
class Func:
    """``NAME[arg]`` (``ATAN[a]/[b]`` has two arguments)."""

    name: str
    args: tuple[Expr, ...]


Expr = Num | Var | Unary | Binary | Func

FUNCTIONS = frozenset(
    {
        "SIN",
        "COS",
        "TAN",
        "ATAN",
        "ASIN",
        "ACOS",
        "SQRT",
        "ABS",
        "ROUND",
        "FIX",
        "FUP",
        "LN",
        "EXP",
        "BIN",
        "BCD",
    }
)
COMPARISONS = frozenset({"EQ", "NE", "GT", "GE", "LT", "LE"})
LOGIC = frozenset({"AND", "OR", "XOR"})
KEYWORDS = FUNCTIONS | COMPARISONS | LOGIC | {"MOD", "IF", "THEN", "GOTO", "WHILE", "DO", "END"}

_TOKEN = re.compile(r"\s*(?:(\d+(?:\.\d*)?|\.\d+)|([A-Z]+)|(.))")


def tokenize(text: str) -> list[str]:
    """Split upper-case block text into numbers, words and single characters."""
    return _tokens_at(text)[0]


def _tokens_at(text: str) -> tuple[list[str], list[int]]:
    """The tokens of :func:`tokenize` and the 0-based column where each starts (a word
    split into single letters gives each letter its own column)."""
    tokens: list[str] = []
    columns: list[int] = []
    for match in _TOKEN.finditer(text):
        number, word, char = match.groups()
        if number is not None:
            tokens.append(number)
            columns.append(match.start(1))
        elif word is not None:
            at = match.start(2)
            for part in _split_word(word):
                tokens.append(part)
                columns.append(at)
                at += len(part)
        elif char is not None and not char.isspace():
            tokens.append(char)
            columns.append(match.start(3))
    return tokens, columns


def _split_word(word: str) -> list[str]:
    """A run of letters is a keyword, or single-letter addresses (``G91X`` has none)."""
    if word in KEYWORDS:
        return [word]
    for keyword in sorted(KEYWORDS, key=len, reverse=True):
        if word.endswith(keyword) and len(word) > len(keyword):
            return [*_split_word(word[: -len(keyword)]), keyword]
    return list(word)


class _Parser:
    def __init__(
        self, tokens: list[str], source: str, columns: list[int] | None = None, base: int = 0
    ) -> None:
        self.tokens = tokens
        self.pos = 0
        self.source = source
        self.columns = columns
        self.base = base  # column of the parsed text's first character in the source line

    def error(self, what: str) -> InputError:
        return InputError(f"{what} in block {self.source!r}")

    def peek(self, offset: int = 0) -> str | None:
        index = self.pos + offset
        return self.tokens[index] if index < len(self.tokens) else None

    def take(self) -> str:
        token = self.peek()
        if token is None:
            raise self.error("unexpected end")
        self.pos += 1
        return token

    def expect(self, token: str) -> None:
        got = self.take()
        if got != token:
            raise self.error(f"expected {token!r}, found {got!r}")

    def close(self, opened: int) -> None:
        """Expect the ``]`` that closes the ``[`` at token index ``opened``."""
        found = self.peek()
        if found == "]":
            self.pos += 1
            return
        where = ""
        if self.columns is not None:
            where = f" at column {self.base + self.columns[opened] + 1}"
        after = f" (found {found!r})" if found is not None else ""
        raise self.error(f"missing ']' to close the '['{where}{after}")

    def at_end(self) -> bool:
        return self.pos >= len(self.tokens)

    # logic < comparison < additive < multiplicative < unary < primary
    def expression(self) -> Expr:
        left = self.comparison()
        while self.peek() in LOGIC:
            op = self.take()
            left = Binary(op, left, self.comparison())
        return left

    def comparison(self) -> Expr:
        left = self.additive()
        if self.peek() in COMPARISONS:
            op = self.take()
            left = Binary(op, left, self.additive())
        return left

    def additive(self) -> Expr:
        left = self.multiplicative()
        while self.peek() in ("+", "-"):
            op = self.take()
            left = Binary(op, left, self.multiplicative())
        return left

    def multiplicative(self) -> Expr:
        left = self.unary()
        while self.peek() in ("*", "/", "MOD"):
            op = self.take()
            left = Binary(op, left, self.unary())
        return left

    def unary(self) -> Expr:
        if self.peek() in ("+", "-"):
            op = self.take()
            return Unary(op, self.unary())
        return self.primary()

    def primary(self) -> Expr:
        token = self.take()
        if token[0].isdigit() or token[0] == ".":
            try:
                value = float(token)
            except ValueError:
                raise self.error(f"bad number {token!r}") from None
            if not math.isfinite(value) or len(token) - token.count(".") > MAX_DIGITS:
                # no control takes a word of this many digits (Fanuc and Haas take about 8);
                # a longer one is a damaged file, and a float of it may overflow to infinity
                shown = token if len(token) <= 12 else f"{token[:12]}... ({len(token)} digits)"
                raise self.error(f"number {shown} is out of range")
            return Num(value if "." in token else int(token))
        if token == "#":
            return Var(self.primary())
        if token == "[":
            opened = self.pos - 1
            inner = self.expression()
            self.close(opened)
            return inner
        if token in FUNCTIONS:
            opened = self.pos
            self.expect("[")
            arg = self.expression()
            self.close(opened)
            if token == "ATAN" and self.peek() == "/" and self.peek(1) == "[":
                self.take()
                opened = self.pos
                self.take()
                second = self.expression()
                self.close(opened)
                return Func(token, (arg, second))
            return Func(token, (arg,))
        raise self.error(f"unexpected {token!r} in expression")


def parse_expression(text: str) -> Expr:
    """Parse a whole expression such as ``#1 + [2 * SIN[30]]``."""
    parser = _Parser(tokenize(text.upper()), text)
    expr = parser.expression()
    if not parser.at_end():
        raise parser.error(f"unexpected {parser.peek()!r}")
    return expr


def evaluate(expr: Expr, lookup: Lookup) -> float | None:
    """Value of ``expr``; ``None`` is the null (undefined) value, 0 in arithmetic."""
    if isinstance(expr, Num):
        return float(expr.value)  # macro values are reals, however the literal was written
    if isinstance(expr, Var):
        return lookup(variable_number(expr.index, lookup))
    if isinstance(expr, Unary):
        value = _num(evaluate(expr.operand, lookup))
        return -value if expr.op == "-" else value
    if isinstance(expr, Func):
        return _function(expr, lookup)
    left, right = evaluate(expr.left, lookup), evaluate(expr.right, lookup)
    op = expr.op
    if op in ("EQ", "NE"):
        same = (
            left == right
            if left is None or right is None
            else math.isclose(left, right, rel_tol=0, abs_tol=1e-9)
        )
        return float(same if op == "EQ" else not same)
    a, b = _num(left), _num(right)
    if op == "+":
        result = a + b
    elif op == "-":
        result = a - b
    elif op == "*":
        result = a * b
    elif op in ("/", "MOD"):
        if b == 0:
            unset = unset_variables(expr.right, lookup)
            if unset:
                names = ", ".join(f"#{n}" for n in unset)
                raise InputError(f"division by zero: {names} {_is_are(unset)} unset (null)")
            raise InputError("division by zero in macro expression")
        result = a / b if op == "/" else math.fmod(a, b)
    elif op in COMPARISONS:
        result = float({"GT": a > b, "GE": a >= b, "LT": a < b, "LE": a <= b}[op])
    else:
        ia, ib = int(a), int(b)
        result = float({"AND": ia & ib, "OR": ia | ib, "XOR": ia ^ ib}[op])
    if not math.isfinite(result):
        raise InputError(f"macro expression overflowed ({op})")
    return result


def unset_variables(expr: Expr, lookup: Lookup) -> tuple[int, ...]:
    """The variables ``expr`` reads that hold the null value (for messages that name the
    cause of a zero, rather than the zero)."""
    found: list[int] = []

    def walk(node: Expr) -> None:
        if isinstance(node, Var):
            walk(node.index)
            try:
                number = variable_number(node.index, lookup)
            except InputError:
                return
            if number != 0 and lookup(number) is None and number not in found:
                found.append(number)
        elif isinstance(node, Unary):
            walk(node.operand)
        elif isinstance(node, Binary):
            walk(node.left)
            walk(node.right)
        elif isinstance(node, Func):
            for arg in node.args:
                walk(arg)

    walk(expr)
    return tuple(found)


def _is_are(names: tuple[int, ...]) -> str:
    return "is" if len(names) == 1 else "are"


def _num(value: float | None) -> float:
    return 0.0 if value is None else value


def variable_number(index: Expr, lookup: Lookup) -> int:
    """The variable number ``#[index]`` refers to (rounded to an integer)."""
    value = _num(evaluate(index, lookup))
    if not 0 <= value < 100000:
        raise InputError(f"no macro variable #{value:g}")
    return round(value)


def _function(expr: Func, lookup: Lookup) -> float:
    args = [_num(evaluate(a, lookup)) for a in expr.args]
    x = args[0]
    name = expr.name
    try:
        if name == "SIN":
            return math.sin(math.radians(x))
        if name == "COS":
            return math.cos(math.radians(x))
        if name == "TAN":
            return math.tan(math.radians(x))
        if name == "ATAN":
            angle = math.degrees(math.atan2(x, args[1]) if len(args) == 2 else math.atan(x))
            return angle % 360.0 if len(args) == 2 else angle
        if name == "ASIN":
            return math.degrees(math.asin(x))
        if name == "ACOS":
            return math.degrees(math.acos(x))
        if name == "SQRT":
            return math.sqrt(x)
        if name == "ABS":
            return abs(x)
        if name == "ROUND":
            return float(math.floor(abs(x) + 0.5) * (1 if x >= 0 else -1))
        if name == "FIX":
            return float(math.floor(x))
        if name == "FUP":
            return float(math.ceil(x))
        if name == "LN":
            return math.log(x)
        if name == "EXP":
            return math.exp(x)
        if name == "BIN":
            return float(int(f"{int(x):x}", 10)) if x >= 0 else 0.0
        return float(int(str(int(abs(x))), 16))  # BCD
    except (ValueError, OverflowError) as exc:
        raise InputError(f"{name}[{x:g}] is out of range") from exc


# --------------------------------------------------------------------------- statements


@dataclass(frozen=True, slots=True)
class Assign:
    """``#target = value``."""

    target: Expr
    value: Expr


@dataclass(frozen=True, slots=True)
class Goto:
    """``GOTO n``: continue at the block numbered ``Nn``."""

    target: Expr


@dataclass(frozen=True, slots=True)
class IfGoto:
    """``IF [condition] GOTO n``."""

    condition: Expr
    target: Expr


@dataclass(frozen=True, slots=True)
class IfThen:
    """``IF [condition] THEN #a = b``."""

    condition: Expr
    then: Assign


@dataclass(frozen=True, slots=True)
class While:
    """``WHILE [condition] DOm``."""

    condition: Expr
    loop: int


@dataclass(frozen=True, slots=True)
class EndLoop:
    """``ENDm``: jump back to the matching ``WHILE``."""

    loop: int


@dataclass(frozen=True, slots=True)
class Dprnt:
    """``DPRNT[...]`` with its parsed items."""

    items: tuple[dprnt.Item, ...]


@dataclass(frozen=True, slots=True)
class PortControl:
    """``POPEN`` (opens the printer port, DC2) or ``PCLOS`` (closes it, DC4)."""

    open: bool


@dataclass(frozen=True, slots=True)
class Words:
    """Ordinary address words: ``(letter, expression)`` in block order."""

    words: tuple[tuple[str, Expr], ...]

    def values(self, letter: str) -> list[Expr]:
        """Every expression given for ``letter`` (G and M may repeat)."""
        return [expr for addr, expr in self.words if addr == letter]


Statement = Assign | Goto | IfGoto | IfThen | While | EndLoop | Dprnt | PortControl | Words


@dataclass(frozen=True, slots=True)
class Block:
    """One parsed block: its N number (if any), block-delete flag and statement."""

    source: str
    number: int | None = None
    deleted: bool = False
    statement: Statement = field(default_factory=lambda: Words(()))


_COMMENT = re.compile(r"\([^)]*\)?")
_N_WORD = re.compile(r"^\s*N\s*(\d+)", re.IGNORECASE)
_DPRNT = re.compile(r"^\s*DPRNT\s*\[", re.IGNORECASE)


# A block of plain address words with literal numbers (most of any real program): parsed by
# one regular expression instead of the tokenizer; anything else takes the full parser.
# Numbers are written so that a digit string splits one way only, and the repetition is
# possessive: a long line that fails to match fails in linear time (no backtracking blow-up).
MAX_DIGITS = 32
"""Digits of a number word beyond which the parser refuses it (docs/check.md#g-code; Ours)."""

# At most 32 digits a part: a longer number (a float may overflow to infinity) takes the full
# parser, which refuses a value out of range with a typed error.
_PLAIN_BLOCK = re.compile(r"(?:[A-Z][+-]?(?:\d{1,32}(?:\.\d{0,32})?|\.\d{1,32}) *)++")
_PLAIN_WORD = re.compile(r"([A-Z])([+-]?(?:\d+(?:\.\d*)?|\.\d+))")
# A whole line of plain words (``N120 G01 X1.5 Y-2. F300.``): the common case, parsed by one
# match; literal numbers repeat a lot (G01, Z-1., F300.), so their Num values are shared.
_PLAIN_LINE = re.compile(
    r"\s*+(?:N(\d+))? *((?:[A-Z][+-]?(?:\d{1,32}(?:\.\d{0,32})?|\.\d{1,32}) *)++)"
)
_NUMBERS: dict[str, Num] = {}
# The bulk of a surface program from a CAM post: ``X12.345 Y-6.7 Z-1.05`` (an N number and an
# F now and then), every number with a decimal point (parse_axes). One match gives the numbers
# by axis, without the word-by-word scan; a line it matches, _PLAIN_LINE matches with the same
# N number and the same words. Another letter, order or repeated axis, or a number without a
# point, is left to the general pattern.
_POINT = r"[+-]?(?:\d{1,32}\.\d{0,32}|\.\d{1,32})"
_XYZF_LINE = re.compile(
    rf"\s*+(?:N(\d+) *)?(?=[XYZF])(?:X({_POINT}) *)?(?:Y({_POINT}) *)?(?:Z({_POINT}) *)?"
    rf"(?:F({_POINT}) *)?"
)


def _number(text: str) -> Num:
    found = _NUMBERS.get(text)
    if found is None:
        if len(_NUMBERS) > 4096:
            _NUMBERS.clear()
        found = _NUMBERS[text] = Num(_literal(text))
    return found


def _literal(text: str) -> float:
    """A word's number as written: an int without a decimal point, else a float."""
    return float(text) if "." in text else int(text)


PlainWords = tuple[tuple[str, float], ...]
"""Letters and numbers; one written without a decimal point is an ``int`` (see :class:`Num`)."""


def parse_axes(line: str) -> tuple[int | None, dict[str, float]] | None:
    """N number and values of a line of X, Y, Z and F words only, in that order, each number
    with a decimal point (``N10 X12.345 Y-6.7 Z-1.05``), or None for any other line.

    The bulk of a surface program, read by one match into what a dry run moves by; the
    words are those :func:`parse_plain` and :func:`parse_block` give (floats, as written).
    """
    found = _XYZF_LINE.fullmatch(line.rstrip("\r\n;"))
    if found is None:
        return None
    number, x, y, z, f = found.groups()
    axes: dict[str, float] = {}
    if x is not None:
        axes["X"] = float(x)
    if y is not None:
        axes["Y"] = float(y)
    if z is not None:
        axes["Z"] = float(z)
    if f is not None:
        axes["F"] = float(f)
    return (int(number) if number else None), axes


def parse_plain(line: str) -> tuple[int | None, PlainWords] | None:
    """N number and words of a line of plain literal words, or None for any other line.

    The fast path of a dry run: ``N120 G01 X1.5 Y-2. F300.`` needs no expression
    evaluation; :func:`parse_block` gives the same words as :class:`Num` expressions.
    """
    plain = _PLAIN_LINE.fullmatch(line.rstrip("\r\n;"))
    if plain is None:
        return None
    number, body = plain.groups()
    words = tuple(
        [
            (letter, float(value) if "." in value else int(value))
            for letter, value in _PLAIN_WORD.findall(body)
        ]
    )
    return (int(number) if number else None), words


def parse_block(line: str) -> Block:
    """Parse one program line (without its EOB) into a :class:`Block`."""
    source = line.rstrip("\r\n;")
    plain = _PLAIN_LINE.fullmatch(source)
    if plain is not None:
        number, body = plain.groups()
        words = tuple([(letter, _number(value)) for letter, value in _PLAIN_WORD.findall(body)])
        return Block(source, int(number) if number else None, False, Words(words))
    body = source.lstrip()
    if body.strip() == "%":  # tape delimiter inside a stream: nothing to execute
        return Block(source)
    base = len(source) - len(body)  # where body starts in the line, for error columns
    deleted = body.startswith("/")
    if deleted:
        body = body[1:]
        base += 1
    number = None
    if match := _N_WORD.match(body):
        number = int(match.group(1))
        body = body[match.end() :]
        base += match.end()
    if _DPRNT.match(body):
        # DPRNT text is kept as written: its own case and parentheses-free text rules
        return Block(source, number, deleted, Dprnt(dprnt.parse_statement(body)))
    # comments become blanks of their own length, so columns stay those of the line
    masked = _COMMENT.sub(lambda m: " " * len(m.group()), body).upper()
    code = masked.strip().rstrip(";").strip()
    base += len(masked) - len(masked.lstrip())
    statement = _parse_statement(code, source, base) if code else Words(())
    return Block(source, number, deleted, statement)


def _parse_statement(code: str, source: str, base: int = 0) -> Statement:
    if _PLAIN_BLOCK.fullmatch(code):
        return Words(
            tuple((letter, Num(_literal(value))) for letter, value in _PLAIN_WORD.findall(code))
        )
    if code in ("POPEN", "PCLOS"):
        return PortControl(code == "POPEN")
    tokens, columns = _tokens_at(code)
    parser = _Parser(tokens, source, columns, base)
    first = parser.peek()
    if first == "#":
        assign = _assignment(parser)
        _finish(parser)
        return assign
    if first == "IF":
        parser.take()
        condition = _bracketed(parser)
        keyword = parser.take()
        if keyword == "GOTO":
            statement: Statement = IfGoto(condition, parser.unary())
        elif keyword == "THEN":
            statement = IfThen(condition, _assignment(parser))
        else:
            raise parser.error(f"IF needs GOTO or THEN, found {keyword!r}")
        _finish(parser)
        return statement
    if first == "GOTO":
        parser.take()
        statement = Goto(parser.unary())
        _finish(parser)
        return statement
    if first == "WHILE":
        parser.take()
        condition = _bracketed(parser)
        parser.expect("DO")
        statement = While(condition, _loop_number(parser))
        _finish(parser)
        return statement
    if first == "END":
        parser.take()
        statement = EndLoop(_loop_number(parser))
        _finish(parser)
        return statement
    words: list[tuple[str, Expr]] = []
    while not parser.at_end():
        letter = parser.take()
        if len(letter) != 1 or not letter.isalpha():
            raise parser.error(f"expected an address letter, found {letter!r}")
        following = parser.peek()
        if following is None or (len(following) == 1 and following.isalpha()):
            raise InputError(f"address {letter} has no value in block {source!r}")
        words.append((letter, parser.unary()))
    return Words(tuple(words))


def _assignment(parser: _Parser) -> Assign:
    parser.expect("#")
    target = parser.primary()
    parser.expect("=")
    return Assign(target, parser.expression())


def _bracketed(parser: _Parser) -> Expr:
    opened = parser.pos
    parser.expect("[")
    inner = parser.expression()
    parser.close(opened)
    return inner


def _loop_number(parser: _Parser) -> int:
    token = parser.take()
    if not token.isdigit() or not 1 <= int(token) <= 3:
        raise parser.error(f"loop number must be 1, 2 or 3, found {token!r}")
    return int(token)


def _finish(parser: _Parser) -> None:
    if not parser.at_end():
        raise parser.error(f"unexpected {parser.peek()!r}")


# --------------------------------------------------------------------------- program text

_O_NUMBER = re.compile(r"^\s*[O:](\d{1,5})\s*(?:\((.*)\))?", re.IGNORECASE)


@dataclass(frozen=True, slots=True)
class ProgramHeader:
    """The ``O`` number and optional title comment of a program."""

    number: int
    title: str = ""

    @property
    def name(self) -> str:
        """``O00123`` style name (five digits, as NGC shows it)."""
        return f"O{self.number:05d}"


def program_lines(text: str) -> list[str]:
    """Body lines of a tape-format program: ``%`` lines and the ``O`` line removed."""
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    body: list[str] = []
    for line in lines:
        stripped = line.strip().strip("\x1a")
        if stripped == "%" or not stripped:
            continue
        if not body and _O_NUMBER.match(stripped):
            continue
        body.append(stripped)
    return body


def parse_header(text: str) -> ProgramHeader:
    """Find the ``O`` number of a program; :class:`InputError` if there is none."""
    for line in text.replace("\r", "\n").split("\n"):
        stripped = line.strip()
        if not stripped or stripped == "%":
            continue
        match = _O_NUMBER.match(stripped)
        if match is None:
            break
        return ProgramHeader(int(match.group(1)), (match.group(2) or "").strip())
    raise InputError("program has no O number on its first line")
