"""The HTML report of a diagnosis run: one file, nothing outside it, the run's own numbers
(the report of a real run: tests/models/diagnosis/test_workflow.py)."""

from __future__ import annotations

import base64
import re
import struct
import zlib

import pytest

from mcpilco.models.diagnosis.html_report import DiagnosisReport, verdict_status


def external_references(text: str) -> list[str]:
    """Everything in ``text`` that would make a browser read another file or the network."""
    bad = [m for m in re.findall(r'src="([^"]*)"', text) if not m.startswith("data:image/png;")]
    bad += [m for m in re.findall(r'href="([^"]*)"', text) if not m.startswith("#")]
    bad += re.findall(r"https?://[^\s\"')<]+", text)
    bad += re.findall(r"@import|url\(", text)
    return bad


def png_bytes() -> bytes:
    """A 1x1 PNG built by hand (signature, IHDR, IDAT, IEND chunks with their CRCs)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    ihdr = struct.pack(">IIBBBBB", 1, 1, 8, 2, 0, 0, 0)  # 1x1, 8-bit RGB
    idat = zlib.compress(b"\x00\xff\x00\x00")  # filter byte + one red pixel
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def small_report(**kw) -> DiagnosisReport:
    args = dict(
        title="arm <1>",
        verdict="v1: unexplained: joint 2 at 1.40x the noise floor",
        versions=["v0: start", "v1: start + viscous:2"],
        heldout_rmse=[[1.0, 3.0], [1.0, 1.4]],
        floors=[[1.0, 1.0], [1.0, 1.0]],
    )
    args.update(kw)
    return DiagnosisReport(**args)


def test_report_embeds_figures_and_renders_the_corrected_parameters():
    png = png_bytes()
    corrected = {
        "joint2 damping": {"value": 0.5, "ci95": 0.01, "unit": "N·m·s/rad"},
        "joint2 frictionloss": {"value": 0.3, "ci95": 0.02, "unit": "N·m"},
    }
    text = small_report(figures=[("time <plot>", png)], corrected=corrected).html()
    assert external_references(text) == []
    (data,) = re.findall(r'src="data:image/png;base64,([^"]*)"', text)
    assert base64.b64decode(data) == png  # the figure itself, not a reference to it
    assert "time &lt;plot&gt;" in text and "arm &lt;1&gt;" in text  # text is escaped
    for name, row in corrected.items():
        assert f"<td>{name}</td>" in text
        assert f"<td>{row['value']:.4g}</td><td>{row['ci95']:.4g}</td>" in text
    assert '<span class="high">1.40x</span>' in text and '<span class="good">1.00x</span>' in text
    assert '<span class="tag unexplained">unexplained residual</span>' in text


def test_report_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="heldout_rmse"):
        small_report(heldout_rmse=[[1.0, 2.0]])
    with pytest.raises(TypeError, match="corrected must be a mapping"):
        small_report(corrected=[("damping", 0.5)])
    not_png = tmp_path / "fig.png"
    not_png.write_bytes(b"GIF89a")
    with pytest.raises(ValueError, match="is not a PNG"):
        small_report(figures=[("fig", not_png)]).html()


def test_verdict_status_reads_what_the_verdict_says():
    assert verdict_status("v0: no significant missing effect (...)") == "ok"
    assert verdict_status("v0: missing effect: viscous friction on joint 2 (...)") == "effect"
    assert verdict_status("v0: missing effect: x; with it, joint 2 remains unexplained") == (
        "unexplained"
    )
    assert verdict_status("v0: not enough data: 100 held-out rows") == "nodata"
