"""Content-Security-Policy for the dashboard's page and the login page, computed from the
pages themselves at start-up (never hard-coded: a viser upgrade changes the hashes).

viser 1.1 ships one ``index.html`` whose only script is an inline loader (viser's
``vite-plugin-compress-html.mts``). The loader decodes a gzipped zstd WASM decoder
(``WebAssembly.instantiate``: ``'wasm-unsafe-eval'``), base-88-decodes and decompresses
``data-p`` (the CSS, ``data-ss`` bytes, then the app's JavaScript, ``data-cs`` bytes), and
inserts a ``<style>`` and a ``<script type="module">`` whose text is the whole app. Both
scripts are inline, so ``script-src`` lists exactly their two SHA-256 hashes — the module's
over the UTF-8 text the loader's ``TextDecoder`` yields — and nothing else runs: no inline
handler, no ``javascript:`` URL, no ``<script>`` or ``srcdoc`` frame a stored string could
smuggle in. The app starts its WebSocket worker from a ``blob:`` URL (``worker-src blob:``),
fetches ``data:`` URLs (its HDR environment and a WASM decoder: ``connect-src 'self'
data:``), and needs inline styles (``<style>`` elements it inserts, Mantine's, and style
attributes): ``style-src 'self' 'unsafe-inline'``. ``connect-src 'self'`` also stops the
client from following a ``?websocket=URL`` link to another server (a fake machine).

One violation always remains and is harmless: the Gaussian-splat sorter's emscripten glue
calls ``Function(...)`` at start-up (blocked; the dashboard has no splats).
"""

from __future__ import annotations

import base64
import functools
import hashlib
import re
from pathlib import Path

import numpy as np
import viser
import zstandard

INDEX = Path(viser.__file__).resolve().parent / "client" / "build" / "index.html"
_B88 = "".join(c for c in map(chr, range(0x21, 0x7F)) if c not in "\"&<>'`")
_B88_LUT = np.full(256, -1, dtype=np.int64)
_B88_LUT[np.frombuffer(_B88.encode("ascii"), dtype=np.uint8)] = np.arange(88)
_B88_WEIGHTS = np.array([88**4, 88**3, 88**2, 88, 1], dtype=np.uint64)
_SCRIPT = re.compile(r"<script([^>]*)>(.*?)</script>", re.S)
_STYLE = re.compile(r"<style[^>]*>(.*?)</style>", re.S)


class PageShapeError(RuntimeError):
    """viser's page is not shaped as this module expects: review the policy."""


def from_base88(text: str) -> bytes:
    """viser's base-88 (4 bytes in 5 characters; a final group of k characters holds k − 1
    bytes), as the loader decodes it."""
    digits = _B88_LUT[np.frombuffer(text.encode("ascii"), dtype=np.uint8)]
    if (digits < 0).any():
        raise PageShapeError("viser's packed page holds a character outside base-88")
    full = len(digits) - len(digits) % 5
    groups = digits[:full].reshape(-1, 5).astype(np.uint64) @ _B88_WEIGHTS
    out = groups.astype(">u4").tobytes()
    rest = digits[full:]
    if len(rest):
        v = 0
        for d in rest.tolist():
            v = v * 88 + d
        out += (v % 256 ** (len(rest) - 1)).to_bytes(len(rest) - 1, "big")
    return out


def sha256_source(text: str) -> str:
    """A CSP hash source for an inline script or style."""
    digest = hashlib.sha256(text.encode("utf-8")).digest()
    return f"'sha256-{base64.b64encode(digest).decode()}'"


def _attribute(attrs: str, name: str) -> str:
    found = re.search(rf'{name}="([^"]*)"', attrs)
    if found is None:
        raise PageShapeError(f"viser's loader script has no {name}")
    return found.group(1)


@functools.cache
def viser_scripts(index: Path = INDEX) -> tuple[str, str]:
    """The hash sources of viser's loader and of the app module it inserts."""
    page = index.read_text("utf-8")
    scripts = _SCRIPT.findall(page)
    if len(scripts) != 1 or "data-p=" not in scripts[0][0]:
        raise PageShapeError("viser's index.html no longer has exactly one loader script")
    attrs, loader = scripts[0]
    packed = from_base88(_attribute(attrs, "data-p"))
    css, js = int(_attribute(attrs, "data-ss")), int(_attribute(attrs, "data-cs"))
    payload = zstandard.ZstdDecompressor().decompress(packed, max_output_size=css + js)
    if len(payload) != css + js:
        raise PageShapeError("viser's packed page does not hold data-ss + data-cs bytes")
    module = payload[css:].decode("utf-8")
    return sha256_source(loader), sha256_source(module)


def _policy(script: str, style: str, connect: str) -> str:
    return "; ".join(
        (
            "default-src 'none'",
            f"script-src {script}",
            "worker-src blob:",
            f"connect-src {connect}",
            "img-src 'self' data: blob:",
            f"style-src {style}",
            "font-src 'self' data:",
            "manifest-src 'none'",
            "frame-src 'none'",
            "object-src 'none'",
            "base-uri 'none'",
            "form-action 'self'",
            "frame-ancestors 'none'",
        )
    )


@functools.cache
def dashboard_policy() -> str:
    """The policy of ``/dashboard/`` (viser's page)."""
    loader, module = viser_scripts()
    return _policy(
        f"{loader} {module} 'wasm-unsafe-eval'", "'self' 'unsafe-inline'", "'self' data:"
    )


def page_policy(page: str) -> str:
    """The policy of one of our own pages: its inline scripts and styles by hash, nothing
    else (it has no other resources)."""
    scripts = " ".join(sha256_source(body) for _, body in _SCRIPT.findall(page)) or "'none'"
    styles = " ".join(sha256_source(body) for body in _STYLE.findall(page)) or "'none'"
    return _policy(scripts, styles, "'self'")
