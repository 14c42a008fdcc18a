"""Stored text made safe for viser's markdown and HTML (:mod:`webui.escape`), checked with
independent parsers: markdown-it-py (CommonMark, with GFM's tables, strikethrough and
linkify) and Python's ``html.parser``; and the rule that keeps it the only way in: no other
module of the dashboard makes a markdown or HTML element or sets one's content, and every
template is the code's own literal. (The real browser: ``test_browser_xss.py``.)"""

from __future__ import annotations

import ast
import re
import unicodedata
from html.parser import HTMLParser
from pathlib import Path

import pytest
import viser
from hypothesis import given, settings
from hypothesis import strategies as st
from markdown_it import MarkdownIt

from webui.escape import (
    WORD_JOINER,
    Html,
    HtmlBox,
    Markdown,
    MarkdownBox,
    html,
    html_text,
    md,
    md_lines,
    md_text,
)

ROOT = Path(__file__).resolve().parents[2]
GFM = MarkdownIt("gfm-like")  # tables, strikethrough, autolinks (linkify)
PAYLOADS = (
    '<iframe srcdoc="<script>top.pwned=1</script>">',
    '<img src=x onerror="window.pwned=2">',
    "<script>window.pwned=4</script>",
    "[click me](javascript:window.pwned=6)",
    '<a href="javascript:x">tap</a>',
    "**bold** _it_ ~~s~~ `code` # head",
    "| a | b |",
    "www.evil.example http://evil.example mail@evil.example <http://x.y>",
    "&lt;b&gt; &amp; &#60;i&#62; \\*",
    "1. not a list",
    "- not a list either",
    "line one\nline two\r\n# heading?\n\n    code?",
    "> quote? ![img](x) [ref]: /x",
    "\u202eevil\u202c right-to-left",
)


class Parsed(HTMLParser):
    """The tags and the text of an HTML fragment."""

    def __init__(self, fragment: str) -> None:
        super().__init__(convert_charrefs=True)
        self.tags: list[str] = []
        self.text = ""
        self.feed(fragment)
        self.close()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)

    def handle_data(self, data: str) -> None:
        self.text += data


def rendered(markdown: str) -> Parsed:
    return Parsed(GFM.render(markdown).replace(WORD_JOINER, ""))


def one_line(s: str) -> str:
    """What a reader should see of ``s``: one line, spaces collapsed, no bidi overrides."""
    s = re.sub(r"[\r\n]+", " ", unicodedata.normalize("NFC", s))
    s = s.replace("\u202e", "").replace("\u202c", "")
    return re.sub(r" +", " ", s).strip()


@pytest.mark.parametrize("payload", PAYLOADS)
def test_a_payload_in_markdown_is_its_literal_text(payload: str) -> None:
    out = rendered(md_text(payload))
    assert out.tags == ["p"]  # one paragraph: no HTML, link, emphasis, list, heading, table
    assert out.text.strip() == one_line(payload)


@settings(max_examples=300, deadline=None)
@given(st.text(st.characters(exclude_categories=("Cc", "Cs", "Cf", "Zl", "Zp")), max_size=60))
def test_any_text_in_markdown_is_its_literal_text(text: str) -> None:
    out = rendered(md_text(text))
    expected = one_line(text)
    assert out.tags == (["p"] if expected else [])
    assert out.text.strip() == expected


def test_templates_keep_their_markdown_and_escape_their_values() -> None:
    out = rendered(md("Stored optimum for {}: **{:.3f} rad/s**", "<b>x</b>*y*", 3.14159))
    assert out.tags == ["p", "strong"]
    assert out.text.strip() == "Stored optimum for <b>x</b>*y*: 3.142 rad/s"
    table = md("| # | name |\n|---|---|\n| {} | {} |", 7, "a | b | c")
    out = rendered(table)
    assert out.tags.count("td") == 2  # the name's bars split no cell
    assert out.text.replace("\n", "").endswith("7a | b | c")
    inner = md("**{}**", "<i>")
    assert md("{} and {}", inner, "<i>") == Markdown("**&#60;i&#62;** and &#60;i&#62;")
    lines = rendered(md_lines([md("a {}", "<x>"), md("b")]))
    assert lines.tags == ["p", "br"] and lines.text.replace("\n", "") == "a <x>b"


@pytest.mark.parametrize("payload", PAYLOADS)
def test_a_payload_in_html_is_its_literal_text(payload: str) -> None:
    out = Parsed(html('<span title="{}">{}</span>', payload, payload))
    assert out.tags == ["span"]
    assert out.text.strip() == one_line(payload)
    assert Parsed(f"<b>{html_text(payload)}</b>").tags == ["b"]


def test_the_boxes_take_escaped_text_only() -> None:
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        box = MarkdownBox(server.gui, md("**{}**", "<x>"))
        with pytest.raises(TypeError):
            box.show("<img src=x onerror=alert(1)>")  # type: ignore[arg-type]
        with pytest.raises(TypeError):
            box.show(md("a") + "<b>")  # type: ignore[arg-type]  (str + Markdown is a str)
        with pytest.raises(TypeError):
            MarkdownBox(server.gui, "plain")  # type: ignore[arg-type]
        box.show(md("{}", "ok"))
        assert box.handle.content == "ok"
        with pytest.raises(TypeError):
            HtmlBox(server.gui, "<b>x</b>")  # type: ignore[arg-type]
        assert HtmlBox(server.gui, Html("<b>x</b>")).handle.content == "<b>x</b>"
    finally:
        server.stop()


# -- the rule: markdown and HTML reach viser only through webui.escape --------------------------
SINKS = {"add_markdown", "add_html"}
MAKERS = {"md", "html", "Markdown", "Html"}


def dashboard_modules() -> list[tuple[str, ast.Module]]:
    return [
        (str(p.relative_to(ROOT)), ast.parse(p.read_text(encoding="utf-8")))
        for p in sorted((ROOT / "webui").rglob("*.py"))
        if p.name != "escape.py"
    ]


def called(node: ast.Call) -> str | None:
    f = node.func
    return f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else None


def test_only_the_escape_module_makes_markdown_and_html_elements() -> None:
    bad = []
    for path, tree in dashboard_modules():
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and called(node) in SINKS:
                bad.append(f"{path}:{node.lineno} {called(node)}()")
            if isinstance(node, ast.Call) and called(node) in ("Markdown", "Html"):
                bad.append(f"{path}:{node.lineno} {called(node)}(…) made by hand")
            targets = node.targets if isinstance(node, ast.Assign) else []
            for t in targets:
                if isinstance(t, ast.Attribute) and t.attr == "content":
                    bad.append(f"{path}:{node.lineno} .content =")
            if isinstance(node, ast.Call) and called(node) == "setattr":
                if len(node.args) > 1 and getattr(node.args[1], "value", None) == "content":
                    bad.append(f"{path}:{node.lineno} setattr(…, 'content')")
    assert not bad, bad


def test_every_template_is_a_literal() -> None:
    bad = []
    for path, tree in dashboard_modules():
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and called(node) in ("md", "html"):
                first = node.args[0] if node.args else None
                literal = isinstance(first, ast.Constant) and isinstance(first.value, str)
                constant = isinstance(first, ast.Name) and first.id.isupper()
                if not (literal or constant):
                    bad.append(f"{path}:{node.lineno} {called(node)}({ast.unparse(first or node)})")
    assert not bad, bad
