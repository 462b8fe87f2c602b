"""VRML97 reader: bytes -> text -> a generic node tree (no geometry here; see `vehicle.scene`).

Why our own: nothing maintained reads the files we meet. PyVRML97 2.3.1 crashes on any PROTO and
2.4.0a3 is an alpha that yields no meshes and has no gzip or Inline; VTK's importer segfaults on some
real files and silently returns partial scenes; pymeshlab rejects half of them and merges shapes.
VRML's syntax is small, so a regex tokenizer and a recursive-descent parser are enough.

The parser is generic: a field value is read from its syntax alone (numbers, strings, booleans, nodes,
or a bracketed list of one of these), so unknown fields and prototyped node types parse without a
schema. What cannot be read that way (PROTO and EXTERNPROTO declarations, ROUTE statements, Script
bodies) is skipped and counted. Every problem raises `SceneError` with file, line and column.
"""

import gzip
import io
import re
import zlib
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

HEADER = "#VRML V2.0 utf8"
_HEADER = re.compile(r"[ \t]*#VRML[ \t]+V2\.0[ \t]+utf-?8(?:[ \t\r\n]|$)", re.IGNORECASE)  # as browsers read it
MAX_DEPTH = 64  # node nesting: real exports use 6-20; parse + walk of an Inline stay < 600 frames
MAX_DECOMPRESSED = 512 * 2**20

_SPACE = re.compile(r"(?:[ \t\r\n,]+|#[^\n\r]*)*")
_NUMBER = r"[+-]?(?:0[xX][0-9a-fA-F]+|(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?)"
_TOKEN = re.compile(
    r'(?P<punct>[{}\[\]])|(?P<string>"(?:[^"\\]|\\.)*")'
    rf'|(?P<number>{_NUMBER}(?=[ \t\r\n,\[\]{{}}#"]|\Z))'
    r"|(?P<ident>[^\x00-\x20\"#',.\[\\\]{}+\-0-9\x7f][^\x00-\x20\"#',\[\\\]{}\x7f]*)",
    re.S,
)
# A bracketed run of plain decimal numbers (point, coordIndex, height...): the bulk of real files,
# converted in one numpy call instead of token by token.
_NUMBER_RUN = re.compile(r"\[([-+.0-9eE \t\r\n,]*)\]")
_BAD_NUMBER = re.compile(r'[^ \t\r\n,\[\]{}#"]+')
_ESCAPE = re.compile(r"\\(.)", re.S)
_LINE = re.compile(r"[^\r\n]*")


class SceneError(Exception):
    """A scene that cannot be read, located in its file: `str()` is `file:line:column: message`."""

    def __init__(self, message: str, file: str = "<string>", line: int = 1, column: int = 1):
        super().__init__(message)
        self.message = message
        self.file = file
        self.line = line
        self.column = column

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}: {self.message}"


@dataclass(eq=False)
class Source:
    """The decoded text of one file, kept to turn character offsets into lines and columns."""

    file: str
    text: str = field(repr=False)

    def error(self, offset: int, message: str) -> SceneError:
        line = self.text.count("\n", 0, offset) + 1
        column = offset - self.text.rfind("\n", 0, offset)
        return SceneError(message, self.file, line, column)


@dataclass(eq=False)
class Node:
    """One node: its type, its fields as parsed, where it starts, and its DEF name if any.

    Field values: numbers -> float ndarray; strings -> list[str]; TRUE/FALSE -> bool; NULL -> None;
    a node -> Node; a bracketed list -> ndarray, list[str], list[bool] or list[Node] (`[]` -> []).
    USE yields the very object that DEF named.
    """

    type: str
    source: Source = field(repr=False)
    offset: int
    name: str | None = None
    fields: dict[str, Any] = field(default_factory=dict)
    field_offsets: dict[str, int] = field(default_factory=dict)

    def error(self, message: str, field_name: str | None = None) -> SceneError:
        """A SceneError at this node, or at one of its fields when given."""
        return self.source.error(self.field_offsets.get(field_name, self.offset), message)


class Token(NamedTuple):
    kind: str  # punct, string, number, ident or eof
    text: str
    start: int
    end: int


def decode(data: bytes, file: str) -> str:
    """Gunzip (detected by its magic bytes, whatever the file name) and decode UTF-8."""
    if data[:2] == b"\x1f\x8b":
        data = _gunzip(data, file)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line_start = data.rfind(b"\n", 0, e.start) + 1
        column = len(data[line_start : e.start].decode("utf-8")) + 1
        line = data.count(b"\n", 0, e.start) + 1
        raise SceneError(f"invalid UTF-8 byte 0x{data[e.start]:02x}", file, line, column) from None


def _gunzip(data: bytes, file: str) -> bytes:
    try:
        with gzip.GzipFile(fileobj=io.BytesIO(data)) as f:
            out = f.read(MAX_DECOMPRESSED + 1)
    except (OSError, EOFError, zlib.error) as e:
        raise SceneError(f"corrupt gzip data: {e}", file) from None
    if len(out) > MAX_DECOMPRESSED:
        raise SceneError(f"decompresses to more than {MAX_DECOMPRESSED >> 20} MB", file)
    return out


def parse(text: str, file: str = "<string>") -> tuple[list[Node], Counter[str]]:
    """Parse VRML97 text into its root nodes and a count of what was skipped, by kind."""
    parser = _Parser(Source(file, text.removeprefix("\ufeff")))
    return parser.document(), parser.skipped


class _Parser:
    """Recursive descent over tokens scanned lazily from a cursor (one token of lookahead)."""

    def __init__(self, source: Source):
        self.source = source
        self.text = source.text
        self.pos = 0
        self.lookahead: Token | None = None
        self.defs: dict[str, Node] = {}
        self.skipped: Counter[str] = Counter()
        self.depth = 0

    # --- tokens -----------------------------------------------------------------------------

    def peek(self) -> Token:
        if self.lookahead is None:
            self.lookahead = self._scan()
        return self.lookahead

    def advance(self) -> Token:
        token = self.peek()
        self.pos = token.end
        self.lookahead = None
        return token

    def expect(self, text: str, after: str = "") -> Token:
        token = self.advance()
        if token.text != text:
            raise self.unexpected(token, f"'{text}' after {after}" if after else f"'{text}'")
        return token

    def unexpected(self, token: Token, wanted: str) -> SceneError:
        found = "end of file" if token.kind == "eof" else repr(token.text[:40])
        return self.source.error(token.start, f"expected {wanted} but found {found}")

    def _scan(self) -> Token:
        start = _SPACE.match(self.text, self.pos).end()
        if start == len(self.text):
            return Token("eof", "", start, start)
        match = _TOKEN.match(self.text, start)
        if match is None:
            raise self._bad_token(start)
        return Token(match.lastgroup, match.group(), start, match.end())

    def _bad_token(self, start: int) -> SceneError:
        char = self.text[start]
        if char == '"':
            return self.source.error(start, "unterminated string")
        if char in "+-.0123456789":
            return self.source.error(start, f"bad number {_BAD_NUMBER.match(self.text, start).group()!r}")
        return self.source.error(start, f"unexpected character {char!r}")

    def number(self, token: Token) -> float:
        try:
            value = float(int(token.text, 16)) if "x" in token.text.lower() else float(token.text)
        except OverflowError:
            value = np.inf
        if not np.isfinite(value):
            raise self.source.error(token.start, f"number out of range {token.text!r}")
        return value

    # --- statements -------------------------------------------------------------------------

    def document(self) -> list[Node]:
        if not _HEADER.match(self.text):
            found = self.text[:40].partition("\n")[0].rstrip("\r")
            raise self.source.error(0, f"expected header {HEADER!r} but found {found!r}")
        self.pos = _LINE.match(self.text).end()  # the rest of the header line is a comment
        nodes = []
        while self.peek().kind != "eof":
            node = self.statement()
            if node is not None:
                nodes.append(node)
        return nodes

    def statement(self) -> Node | None:
        """A node statement, or a skipped PROTO/EXTERNPROTO/ROUTE (-> None)."""
        if self.skip_declaration():
            return None
        token = self.peek()
        if token.kind != "ident" or token.text in ("TRUE", "FALSE", "NULL"):
            raise self.unexpected(token, "a node")
        return self.node_statement()

    def skip_declaration(self) -> bool:
        """Skip a PROTO, EXTERNPROTO or ROUTE if one starts here; tell whether it did."""
        keyword = self.peek().text
        if keyword == "PROTO":
            self.advance()
            self.expect_ident("a PROTO name")
            self.skip_block("[", "]")
            self.skip_block("{", "}")
        elif keyword == "EXTERNPROTO":
            self.advance()
            self.expect_ident("an EXTERNPROTO name")
            self.skip_block("[", "]")
            self.skip_url()
        elif keyword == "ROUTE":
            self.advance()
            self.expect_ident("an event name")
            self.expect("TO")
            self.expect_ident("an event name")
        else:
            return False
        self.skipped[f"{keyword} {'statement' if keyword == 'ROUTE' else 'declaration'}"] += 1
        return True

    def expect_ident(self, wanted: str) -> Token:
        token = self.advance()
        if token.kind != "ident":
            raise self.unexpected(token, wanted)
        return token

    def skip_block(self, opening: str, closing: str) -> None:
        """Skip a bracketed block, nested brackets included, without interpreting it."""
        self.expect(opening)
        depth = 1
        while depth:
            token = self.advance()
            if token.kind == "eof":
                raise self.unexpected(token, f"'{closing}'")
            if token.kind == "punct":
                depth += 1 if token.text in "[{" else -1

    def skip_url(self) -> None:
        if self.peek().text == "[":
            self.skip_block("[", "]")
            return
        token = self.advance()
        if token.kind != "string":
            raise self.unexpected(token, "a URL string")

    def node_statement(self) -> Node:
        """`DEF name Node {...}`, `USE name` or `Node {...}`."""
        token = self.advance()
        if token.text == "USE":
            name = self.expect_ident("a name after USE")
            if name.text not in self.defs:
                raise self.source.error(name.start, f"USE of undefined name {name.text!r}")
            return self.defs[name.text]
        if token.text == "DEF":
            name = self.expect_ident("a name after DEF")
            node = self.node(self.expect_ident("a node type"))
            node.name = name.text
            self.defs[name.text] = node  # after the body: a node cannot USE itself
            return node
        if token.kind != "ident":
            raise self.unexpected(token, "a node")
        return self.node(token)

    def node(self, type_token: Token) -> Node:
        node = Node(type_token.text, self.source, type_token.start)
        if node.type == "Script":  # its interface declarations are not field values
            self.skip_block("{", "}")
            return node
        self.expect("{", after=node.type)
        self.depth += 1
        if self.depth > MAX_DEPTH:
            raise self.source.error(type_token.start, f"nodes nested more than {MAX_DEPTH} deep")
        while self.peek().text != "}":
            if self.peek().kind == "eof":
                raise self.unexpected(self.peek(), "'}'")
            if self.skip_declaration():
                continue
            name = self.expect_ident(f"a field name or '}}' in {node.type}")
            node.field_offsets[name.text] = name.start
            node.fields[name.text] = self.field_value(name.text)
        self.advance()
        self.depth -= 1
        return node

    # --- values -----------------------------------------------------------------------------

    def field_value(self, name: str) -> Any:
        token = self.peek()
        if token.text == "[":
            return self.bracketed()
        if token.kind == "number":
            return np.array(self.run("number"), dtype=np.float64)
        if token.kind == "string":
            return self.run("string")
        if token.kind != "ident":
            raise self.unexpected(token, f"a value for {name}")
        return self.atom()

    def run(self, kind: str) -> list:
        """Consecutive numbers (SFVec3f, SFRotation...) or strings."""
        values = []
        while self.peek().kind == kind:
            token = self.advance()
            values.append(self.number(token) if kind == "number" else _unquote(token.text))
        return values

    def atom(self) -> Any:
        """TRUE, FALSE, NULL or a node statement."""
        text = self.peek().text
        if text in ("TRUE", "FALSE"):
            self.advance()
            return text == "TRUE"
        if text == "NULL":
            self.advance()
            return None
        return self.node_statement()

    def bracketed(self) -> Any:
        fast = self.number_run()
        if fast is not None:
            return fast
        opening = self.expect("[")
        items = []
        while True:
            token = self.peek()
            if token.kind == "punct":
                if token.text != "]":
                    raise self.unexpected(token, "']'")
                self.advance()
                return self.homogeneous(items, opening)
            if token.kind == "eof":
                raise self.unexpected(token, "']'")
            if token.kind == "number" or token.kind == "string":
                items.extend(self.run(token.kind))
            elif not self.skip_declaration():
                if token.text == "NULL":
                    raise self.source.error(token.start, "NULL is not allowed in a list")
                items.append(self.atom())

    def number_run(self) -> list | np.ndarray | None:
        """The fast path for `[ 1 2 3, ... ]`; None when the list needs the token-by-token path."""
        match = _NUMBER_RUN.match(self.text, self.peek().start)
        if match is None:
            return None
        try:
            values = np.array(match.group(1).replace(",", " ").split(), dtype=np.float64)
        except ValueError:
            return None  # a malformed number: the slow path says where
        if not np.isfinite(values).all():
            return None
        self.pos = match.end()
        self.lookahead = None
        return values if values.size else []

    def homogeneous(self, items: list, opening: Token) -> Any:
        kinds = {type(item) for item in items}
        if len(kinds) > 1:
            raise self.source.error(opening.start, "list mixes values of different types")
        if kinds == {float}:
            return np.array(items, dtype=np.float64)
        return items


def _unquote(token: str) -> str:
    return _ESCAPE.sub(r"\1", token[1:-1])
