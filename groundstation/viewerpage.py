"""viser's client page as the station serves it: one change to its bundle, and the policy naming its scripts.

viser's page is one loader script whose ``data-p`` attribute holds its style
and its bundle, zstd-compressed in base-88 (viser's
vite-plugin-compress-html); the loader adds the bundle as an inline module
script, which the policy names by hash, as it names the loader.

The bundle starts viser's Gaussian-splat sorter as it loads, splats or not:
the sorter is WebAssembly with embind, which makes its helpers with
``new Function``, and a page whose policy keeps ``unsafe-eval`` out logs an
EvalError on every load. The station draws no splats, so the page we serve
starts the sorter only when something awaits it (the first splats): the
bundle's eager promise becomes a thenable that makes the promise on first
use. A page that is never sent a splat evaluates no string, and the policy
stays as strict as it was.
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

_LOADER = re.compile(r'<script data-p="([^"]*)" data-ss="(\d+)" data-cs="(\d+)">(.*?)</script>', re.S)
_BASE88 = "".join(chr(c) for c in range(0x21, 0x7F) if chr(c) not in "\"&<>'`")
# the bundle's `X=fetch(WASM_URL).then(e=>e.arrayBuffer()).then(e=>FACTORY({wasmBinary:e}))`, minified names
_EAGER_SORTER = re.compile(rb"([\w$]+)=(fetch\([\w$]+\)\.then\(e=>e\.arrayBuffer\(\)\)"
                           rb"\.then\(e=>[\w$]+\(\{wasmBinary:e\}\)\))")


class ViewerPage:
    """viser's client page, its splat sorter started only on use, and the policy that lets exactly its own
    scripts run."""

    def __init__(self, html: str):
        loader, style, bundle = _unpack(html)
        bundle = lazy_sorter(bundle)
        self.html = _repack(html, style, bundle)
        hashes = " ".join(f"'sha256-{base64.b64encode(hashlib.sha256(s).digest()).decode()}'"
                          for s in (loader, bundle))
        self.policy = (f"default-src 'none'; script-src {hashes} 'wasm-unsafe-eval'; worker-src blob:; "
                       "style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; font-src 'self' data:; "
                       "connect-src 'self' data: blob:; frame-ancestors 'self'; base-uri 'none'; form-action 'none'")

    @classmethod
    @functools.cache
    def of_installed_viser(cls) -> ViewerPage:
        """Made once a process (unpacking and packing the 2.5 MB bundle takes a tenth of a second)."""
        return cls((Path(viser.__file__).parent / "client" / "build" / "index.html").read_text(encoding="utf-8"))


def lazy_sorter(bundle: bytes) -> bytes:
    """The bundle with its splat sorter's module made on first use instead of as the bundle loads."""
    patched, count = _EAGER_SORTER.subn(rb"\1={then(a,b){return(this.p??=\2).then(a,b)}}", bundle)
    if not count:
        raise RuntimeError("viser's bundle does not start its splat sorter as expected (fetch(...wasmBinary...))")
    return patched


def _unpack(html: str) -> tuple[bytes, bytes, bytes]:
    """The loader script, the style and the bundle."""
    found = _LOADER.search(html)
    if found is None:
        raise RuntimeError("viser's client page is not laid out as expected (a loader script with data-p)")
    packed, style_size, code_size, loader = found.group(1), int(found.group(2)), int(found.group(3)), found.group(4)
    unpacked = zstandard.ZstdDecompressor().decompress(_from_base88(packed), max_output_size=style_size + code_size)
    return loader.encode("utf-8"), unpacked[:style_size], unpacked[style_size:style_size + code_size]


def _repack(html: str, style: bytes, bundle: bytes) -> str:
    """The page with ``style`` and ``bundle`` packed into its loader's attributes, as viser's build packs them."""
    found = _LOADER.search(html)
    packed = _to_base88(zstandard.ZstdCompressor(level=9).compress(style + bundle))
    tag = f'<script data-p="{packed}" data-ss="{len(style)}" data-cs="{len(bundle)}">{found.group(4)}</script>'
    return html[:found.start()] + tag + html[found.end():]


def _from_base88(text: str) -> bytes:
    """Every 5 digits are 4 bytes (big-endian); a tail of n digits is n - 1 bytes."""
    lookup = np.zeros(128, dtype=np.uint64)
    lookup[np.frombuffer(_BASE88.encode(), dtype=np.uint8)] = np.arange(88, dtype=np.uint64)
    digits = lookup[np.frombuffer(text.encode("ascii"), dtype=np.uint8)]
    whole = len(digits) // 5
    groups = (digits[:whole * 5].reshape(whole, 5) * np.uint64(88) ** np.arange(4, -1, -1, dtype=np.uint64)).sum(1)
    data = groups.astype(">u4").tobytes()
    rest = digits[whole * 5:]
    if len(rest):
        value = 0
        for digit in rest:
            value = value * 88 + int(digit)
        data += value.to_bytes(len(rest) - 1, "big")
    return data


def _to_base88(data: bytes) -> str:
    """The inverse of ``_from_base88``."""
    whole = len(data) // 4
    groups = np.frombuffer(data[:whole * 4], dtype=">u4").astype(np.uint64)
    digits = np.empty((whole, 5), dtype=np.uint8)
    for place in range(4, -1, -1):
        digits[:, place] = groups % 88
        groups //= 88
    alphabet = np.frombuffer(_BASE88.encode(), dtype=np.uint8)
    text = alphabet[digits.reshape(-1)].tobytes().decode("ascii")
    tail = data[whole * 4:]
    if tail:
        value, out = int.from_bytes(tail, "big"), []
        for _ in range(len(tail) + 1):
            value, digit = divmod(value, 88)
            out.append(_BASE88[digit])
        text += "".join(reversed(out))
    return text
