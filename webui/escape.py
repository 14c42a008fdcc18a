"""Text on the dashboard: the one place where markdown and HTML are made and handed to viser.

viser renders markdown with react-markdown, remark-gfm and a raw-HTML plugin that parses any
HTML in it with the browser's ``DOMParser`` and renders it *unsanitised*; ``add_html`` is
``innerHTML``. So a user named ``<iframe srcdoc="<script>…">`` runs script in the dashboard of
whoever looks at that name (issue 12.1). Here:

- :func:`md_text` turns any string into literal inline markdown text: every ASCII punctuation
  character becomes a decimal character reference, which CommonMark (6.2) treats as literal
  text that "cannot be used in place of symbols indicating structure" — no HTML, link,
  emphasis, code, heading or table cell can start; line breaks and other control characters
  become a space (no new block), bidi controls are dropped (no reversed text), and a word
  joiner (U+2060, invisible) after ``www``, ``:`` before ``//`` and ``@`` stops GFM's
  autolinks, which are found *after* references are decoded.
- :func:`md` fills a template (the code's own literal) with values, each escaped by
  :func:`md_text` unless it is :class:`Markdown` already; it returns :class:`Markdown`.
- :class:`MarkdownBox` / :class:`HtmlBox` are the dashboard's only markdown and HTML
  elements, and they take :class:`Markdown` / :class:`Html` only (a plain ``str`` raises), so
  no string reaches viser's markdown without passing through here. ``tests/dashboard/
  test_escape.py`` checks that no other module calls ``add_markdown``/``add_html`` or sets
  ``.content``, and that every template is a literal.

Labels, dropdown options, text inputs, notifications, tab and chart titles are React text in
viser's client (never parsed as HTML) and need nothing.
"""

from __future__ import annotations

import html as _html
import re
import string
import unicodedata
from collections.abc import Callable, Iterable
from typing import Any

import viser

_LINE = frozenset("\r\n\t\v\f\x85\u2028\u2029")
_BIDI = frozenset("\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069\u200e\u200f\u061c")
WORD_JOINER = "\u2060"
_AUTOLINK = re.compile(r"(?i)www(?=\.)|:(?=//)|@")
_SPACES = re.compile(r" {2,}")
BREAK = "  \n"  # a hard line break in markdown


class Markdown(str):
    """Markdown the dashboard vouches for: its own literals, with data escaped by :func:`md`.
    (Adding a plain ``str`` to it gives a plain ``str``, which :class:`MarkdownBox` refuses.)"""

    __slots__ = ()


class Html(str):
    """HTML the dashboard vouches for: its own literals, with data escaped by :func:`html`."""

    __slots__ = ()


def plain(value: object) -> str:
    """One line of text: NFC, line breaks and tabs as spaces, runs of spaces as one, no
    control, surrogate or bidi-override characters."""
    out = []
    for ch in unicodedata.normalize("NFC", str(value)):
        if ch in _LINE:
            out.append(" ")
        elif ch in _BIDI or unicodedata.category(ch) in ("Cc", "Cs"):
            continue
        else:
            out.append(ch)
    return _SPACES.sub(" ", "".join(out))


def md_text(value: object) -> str:
    """Any value as literal inline markdown text (see the module's docstring)."""
    text = _AUTOLINK.sub(lambda m: m.group(0) + WORD_JOINER, plain(value))
    return "".join(
        f"&#{ord(ch)};" if ch.isascii() and not ch.isalnum() and ch != " " else ch for ch in text
    )


def html_text(value: object) -> str:
    """Any value as literal text in HTML (an element's content or a quoted attribute)."""
    return _html.escape(plain(value), quote=True)


class _Filler(string.Formatter):
    """``str.format`` whose every replacement field is escaped, unless already safe."""

    def __init__(self, escape: Callable[[object], str], safe: type[str]) -> None:
        self.escape, self.safe = escape, safe

    def format_field(self, value: Any, format_spec: str) -> str:
        if type(value) is self.safe and not format_spec:
            return str.__str__(value)
        return self.escape(format(value, format_spec))


_MD = _Filler(md_text, Markdown)
_HTML = _Filler(html_text, Html)


def md(template: str, /, *args: object, **kwargs: object) -> Markdown:
    """``template`` (the code's own markdown, a literal) with its ``{}`` fields filled, each
    value escaped as text (a :class:`Markdown` value is kept as it is)."""
    return Markdown(_MD.vformat(template, args, kwargs))


def md_join(separator: str, parts: Iterable[Markdown]) -> Markdown:
    """Markdown parts joined by ``separator`` (a literal); a part that is not
    :class:`Markdown` is escaped as text."""
    return Markdown(separator.join(p if type(p) is Markdown else md_text(p) for p in parts))


def md_lines(lines: Iterable[Markdown]) -> Markdown:
    """Lines of markdown, one under the other (hard line breaks)."""
    return md_join(BREAK, lines)


def html(template: str, /, *args: object, **kwargs: object) -> Html:
    """``template`` (the code's own HTML, a literal) with its fields filled, each value
    escaped as HTML text (an :class:`Html` value is kept as it is)."""
    return Html(_HTML.vformat(template, args, kwargs))


def _checked(text: str, kind: type[str]) -> str:
    if type(text) is not kind:
        raise TypeError(
            f"{kind.__name__} only (made by webui.escape), got {type(text).__name__}: {text!r:.80}"
        )
    return str.__str__(text)


class MarkdownBox:
    """A markdown element whose content is only ever :class:`Markdown`; :meth:`show` sends
    only what changed."""

    def __init__(self, gui: viser.GuiApi, text: Markdown, **kwargs: Any) -> None:
        self._shown = _checked(text, Markdown)
        self.handle = gui.add_markdown(self._shown, **kwargs)

    def show(self, text: Markdown) -> None:
        new = _checked(text, Markdown)
        if new != self._shown:
            self._shown = new
            self.handle.content = new

    @property
    def text(self) -> str:
        return self._shown


class HtmlBox:
    """An HTML element whose content is only ever :class:`Html`."""

    def __init__(self, gui: viser.GuiApi, content: Html, **kwargs: Any) -> None:
        self._shown = _checked(content, Html)
        self.handle = gui.add_html(self._shown, **kwargs)

    def show(self, content: Html) -> None:
        new = _checked(content, Html)
        if new != self._shown:
            self._shown = new
            self.handle.content = new
