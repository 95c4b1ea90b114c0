"""The README's Python blocks run as written (on a small camera: the block is the README's,
only the scenario it builds is shrunk), and ``starnav --help`` shows each command's
description whole, not cut where its docstring's source lines end."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/lib/x86_64-linux-gnu/libLLVM.so.19.1")

README = Path(__file__).resolve().parents[1] / "README.md"
#: What the test adds to every scenario the README builds: a 96 x 96 px camera at 2 spp.
SMALL = {"camera": {"width": 96, "height": 96, "focal_length_mm": 12.5},
         "render": {"spp": 2}}


def python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_the_readme_python_blocks_run(monkeypatch):
    import starnav.config as config
    from starnav.radiance import RadianceImage

    blocks = python_blocks(README.read_text(encoding="utf-8"))
    assert blocks, "the README has Python blocks"
    real = config.scenario_from_dict

    def small(data=None, overrides=()):
        merged = {**(data or {})}
        for k, v in SMALL.items():
            merged[k] = {**merged.get(k, {}), **v}
        return real(merged, overrides)

    monkeypatch.setattr(config, "scenario_from_dict", small)
    for block in blocks:
        ns: dict = {}
        exec(compile(block, str(README), "exec"), ns)  # noqa: S102 (the README's own code)
        img = ns.get("img")
        if img is not None:  # the rendering example: a lit Moon with its AOVs
            assert isinstance(img, RadianceImage)
            assert np.isfinite(img.L).all() and img.L.max() > 0
            assert img.L.shape == (96, 96) and "mask" in img.aovs


def _commands(app):
    yield from app.registered_commands
    for g in app.registered_groups:
        yield from _commands(g.typer_instance)


@pytest.mark.parametrize("args", [[], ["dataset"], ["hil"], ["dem"]])
def test_help_shows_each_description_whole(args):
    from typer.testing import CliRunner

    from starnav.cli.main import app

    r = CliRunner().invoke(app, [*args, "--help"], env={"COLUMNS": "2000"})
    assert r.exit_code == 0, r.output
    lines = [" ".join(ln.strip("│ ").split()) for ln in r.output.splitlines()]
    shown = 0
    for cmd in _commands(app):
        if cmd.callback is None or not cmd.help:
            continue
        first = cmd.help.split("\n\n")[0]
        assert "\n" not in first
        name = cmd.name or cmd.callback.__name__
        row = [ln for ln in lines if ln.startswith(f"{name} ") and first[:30] in ln]
        if row:
            shown += 1
            assert first in row[0], (name, row[0])
    assert shown >= 2
