"""``starnav stars solve`` on the real frames of tests/data/stars (the tetra3 test set) with only
the camera described, its outputs and its bad-input contract (exit 2, one ``error:`` line, the
other images still solved)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

DATA = Path(__file__).resolve().parents[1] / "data" / "stars"
REF = {r["image"]: r for r in
       json.loads((DATA / "reference_cedar.json").read_text())["images"]}
IMAGES = [DATA / name for name in REF]
CAMERA = ["--set", "camera.focal_length_mm=35", "--set", "camera.pixel_pitch_um=6.9"]


@pytest.fixture(scope="module")
def app():
    from starnav.cli.main import app as main_app

    return main_app


def run(app, args):
    return CliRunner().invoke(app, ["stars", "solve", *[str(a) for a in args]],
                              env={"COLUMNS": "50"})


def error_lines(r) -> list[str]:
    assert "Traceback" not in r.output
    return [ln for ln in r.output.splitlines() if ln.startswith("error:")]


@pytest.fixture(scope="module")
def solved(app, tmp_path_factory):
    """Both real frames and, between them, a file that is not an image."""
    cache = pytest.MonkeyPatch()
    cache.setenv("STARNAV_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
    out = tmp_path_factory.mktemp("solve") / "out"
    bad = out.parent / "notes.tiff"
    bad.write_text("this is not an image")
    r = run(app, [IMAGES[0], bad, IMAGES[1], "--out", out, "--epoch", "2019-07-29T20:47:26",
                  *CAMERA])
    cache.undo()
    return r, out, bad


def unit(ra_deg, dec_deg):
    ra, dec = math.radians(ra_deg), math.radians(dec_deg)
    return np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])


def test_real_frames_solve_and_one_bad_file_does_not_stop_them(solved):
    r, out, bad = solved
    assert r.exit_code == 2
    lines = error_lines(r)
    assert len(lines) == 1 and str(bad) in lines[0] and "not an image" in lines[0]
    doc = json.loads((out / "results.json").read_text())
    rows = {Path(x["image"]).name: x for x in doc["images"]}
    assert rows["notes.tiff"]["status"] == "error"
    for name, ref in REF.items():
        x = rows[name]
        assert x["status"] == "ok", x["reason"]
        sep = math.acos(min(1.0, float(unit(x["ra_deg"], x["dec_deg"])
                                       @ unit(ref["ra_deg"], ref["dec_deg"]))))
        assert math.degrees(sep) * 3600 < 30.0
        assert abs(x["fov_x_deg"] / ref["fov_x_deg"] - 1) < 0.002
        assert x["epoch_source"] == "command line"
        assert abs(x["epoch_jyear"] - 2019.5739) < 1e-3
        q = np.array(x["quaternion_xyzw"])
        assert abs(np.linalg.norm(q) - 1) < 1e-9
        assert len(x["matched"]) == x["n_matched"] >= ref["matches"]
        assert (out / x["overlay"]).is_file()
    report = (out / "report.md").read_text()
    assert "notes.tiff" in report and report.count("| ok |") == 2


def colour_alpha(png: Path) -> tuple[np.ndarray, np.ndarray]:
    """Coverage of the overlay's pure green (circles) and pure magenta (crosses) over the grey
    frame, read back from the PNG: a grey pixel g blended with alpha a into (0, 255, 0) is
    ((1-a) g, (1-a) g + 255 a, (1-a) g), so green-excess / 255 = a where red == blue; any
    other mark under it (labels, squares) breaks red == blue and the pixel is left out."""
    rgb = np.asarray(Image.open(png), int)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return (np.where((r == b) & (g > r), (g - r) / 255.0, 0.0),
            np.where((r == b) & (r > g), (r - g) / 255.0, 0.0))


def fit_circles(alpha: np.ndarray, near: np.ndarray, radius: float) -> np.ndarray:
    """Circles (centre u, v and radius) fitted to the drawn coverage: each covered pixel goes to
    the circle of ``near`` whose ring passes closest (within 2.5 px), then a weighted geometric
    least-squares fit (Gauss-Newton on the distance to the ring). Every covered pixel must
    belong to a circle: no circle is drawn elsewhere."""
    v, u = np.nonzero(alpha)
    w = alpha[v, u]
    p = np.stack([u, v], axis=1).astype(float)
    off = np.abs(np.hypot(*(p[:, None] - near[None]).transpose(2, 0, 1)) - radius)
    k = off.argmin(axis=1)
    assert np.all(off[np.arange(len(k)), k] < 2.5), "green drawn away from every circle"
    out = []
    for j in range(len(near)):
        q, wq = p[k == j], w[k == j]
        assert wq.sum() > np.pi * radius, f"circle {j} not drawn"
        c, r = np.average(q, axis=0, weights=wq), radius
        for _ in range(10):
            dq = q - c
            dist = np.hypot(*dq.T)
            J = np.column_stack([-dq / dist[:, None], -np.ones(len(q))])
            step = np.linalg.solve(J.T @ (J * wq[:, None]), -J.T @ (wq * (dist - r)))
            c, r = c + step[:2], r + step[2]
        out.append([*c, r])
    return np.array(out)


def test_overlay_circles_lie_on_the_detections_and_crosses_on_the_catalogue_stars(solved):
    """Measured from the written PNG: every identified star's circle is centred on its
    detection within 0.5 px, and each catalogue star's cross where the reported solution
    projects it; the crosses lie on the detections within the centroids' own noise."""
    from starnav.stars.catalogue import hipparcos
    from starnav.stars.solve_images import CIRCLE_RADIUS_PX, CROSS_HALF_PX, CROSS_WIDTH_PX

    _, out, _ = solved
    doc = json.loads((out / "results.json").read_text())
    cat = hipparcos()
    for x in doc["images"]:
        if x["status"] != "ok":
            continue
        det = np.array([m["detection_uv_px"] for m in x["matched"]])
        # every detection listed as matched is one of the frame's detections
        dets = np.array(x["detections_uv_px"])
        assert np.all(np.min(np.hypot(*(det[:, None] - dets[None]).transpose(2, 0, 1)),
                             axis=1) < 1e-3)
        png = out / x["overlay"]
        im = Image.open(png)
        assert im.size == (1024, 768) and im.mode == "RGB"
        green, magenta = colour_alpha(png)
        # circles: from the PNG, every one within 0.5 px of its detection (no loosening)
        fit = fit_circles(green, det, CIRCLE_RADIUS_PX)
        d = np.hypot(*(fit[:, :2] - det).T)
        assert np.all(d < 0.5), (d.max(), x["matched"][int(np.argmax(d))]["hip"])
        np.testing.assert_allclose(fit[:, 2], CIRCLE_RADIUS_PX, atol=0.2)
        # the crosses' places are the catalogue stars through the reported camera, recomputed
        # here from results.json alone (pinhole + k1)
        R = np.array(x["R_cam_to_inertial"])
        fx = x["focal_length_mm"] * 1e-3 / 6.9e-6
        rows = [cat.index_of(m["hip"]) for m in x["matched"]]
        c = cat.directions(x["epoch_jyear"], rows) @ R
        xy = c[:, :2] / c[:, 2:]
        r2 = (xy**2).sum(axis=1, keepdims=True)
        pred = fx * xy * (1 + x["k1"] * r2) + np.array([511.5, 383.5])
        np.testing.assert_allclose([m["predicted_uv_px"] for m in x["matched"]], pred,
                                   atol=1e-3)
        # ... and drawn there: the coverage-weighted centre of each cross's magenta, where no
        # other mark lies under the cross (labels of neighbours can) and no other cross is near
        v, u = np.nonzero(magenta)
        p = np.stack([u, v], axis=1).astype(float)
        dist = np.hypot(*(p[:, None] - pred[None]).transpose(2, 0, 1))
        k = dist.argmin(axis=1)
        reach = CROSS_HALF_PX + CROSS_WIDTH_PX + 1
        assert np.all(dist[np.arange(len(k)), k] < reach), "magenta drawn away from every cross"
        rgb = np.asarray(im, int)
        clean = 0
        for j, (pu, pv) in enumerate(pred):
            v0, u0 = int(pv - reach), int(pu - reach)
            v1, u1 = int(pv + reach) + 1, int(pu + reach) + 1
            if min(v0, u0) < 0 or v1 > rgb.shape[0] or u1 > rgb.shape[1]:
                continue  # clipped by the frame's edge
            win = rgb[v0:v1, u0:u1]
            if (np.any(win[..., 0] != win[..., 2])
                    or np.sort(np.hypot(*(pred - pred[j]).T))[1] < 2 * reach):
                continue
            clean += 1
            centre = np.average(p[k == j], axis=0, weights=magenta[v, u][k == j])
            assert np.hypot(*(centre - pred[j])) < 0.05
        assert clean >= 0.5 * len(pred)  # 117 of 162 and 71 of 92 here
        # crosses on the detections: the residual of a correct match is the centroid's noise
        # (its predicted sigma per axis) plus the 0.1 px per-axis floor the bright stars show;
        # for a 2-D Gaussian P(|r| > 4 sigma_total) = exp(-16) ~ 1e-7 per star (~3e-5 over
        # the 254 stars of both frames)
        sig = np.array([m["detection_sigma_px"] for m in x["matched"]])
        r = np.hypot(*(pred - det).T)
        bound = 4.0 * np.sqrt((sig**2).sum(axis=1) + 2 * 0.1**2)
        assert np.all(r <= bound), (r.max(), bound[np.argmax(r / bound)])
        assert np.median(r) < 0.3
        np.testing.assert_allclose(pred - det, -np.array([m["residual_px"] for m in
                                                          x["matched"]]), atol=1e-3)


def test_output_directory_convention(app, solved, tmp_path):
    _, out, _ = solved
    # a non-empty directory is refused before any work
    r = run(app, [IMAGES[1], "--out", out, *CAMERA])
    lines = error_lines(r)
    assert r.exit_code == 2 and "is not empty" in lines[0] and "--overwrite" in lines[0]
    # with --overwrite an earlier solve is replaced; a foreign file stays
    d = tmp_path / "o"
    d.mkdir()
    (d / "notes.txt").write_text("mine")
    (d / "overlay_old.png").write_bytes(b"x")
    blank = tmp_path / "blank.png"
    Image.fromarray(np.full((64, 64), 20, np.uint8)).save(blank)
    r = run(app, [blank, "--out", d, "--overwrite", *CAMERA])
    assert r.exit_code == 2
    assert (d / "notes.txt").read_text() == "mine"
    assert not (d / "overlay_old.png").exists()
    assert (d / "results.json").is_file()


def test_a_frame_not_identified_reports_no_attitude(app, solved, tmp_path, monkeypatch):
    """Six point sources in no sky pattern, on the real frames' camera: "not solved
    (unidentified)" with the counts, exit 1, no attitude in results.json, the overlay without
    circles."""
    monkeypatch.setenv("STARNAV_CACHE_DIR", str(tmp_path / "cache"))
    rng = np.random.default_rng(3)
    frame = rng.normal(100.0, 2.0, (768, 1024))
    for u, v in rng.uniform(100, 600, (6, 2)):
        yy, xx = np.mgrid[int(v) - 8:int(v) + 9, int(u) - 8:int(u) + 9]
        frame[yy, xx] += 400.0 * np.exp(-0.5 * ((xx - u) ** 2 + (yy - v) ** 2) / 0.8**2)
    path = tmp_path / "six.png"
    Image.fromarray(np.round(frame).astype(np.uint16)).save(path)
    # the real frames' epoch: the pattern index the solves above built is reused
    r = run(app, [path, "--out", tmp_path / "o", "--epoch", "2019-07-29T20:47:26", *CAMERA])
    assert r.exit_code == 1 and not error_lines(r), r.output
    assert "six.png: not solved (unidentified): no triangle of the 6 brightest of 6 " \
        "detections verified" in r.output
    row = json.loads((tmp_path / "o" / "results.json").read_text())["images"][0]
    assert row["status"] == "unidentified" and row["n_detections"] == 6
    assert not {"ra_deg", "quaternion_xyzw", "R_cam_to_inertial", "matched"} & set(row)
    green, magenta = colour_alpha(tmp_path / "o" / row["overlay"])
    assert not green.any() and not magenta.any()


def test_no_stars_is_a_one_line_error(app, tmp_path):
    blank = tmp_path / "blank.png"
    Image.fromarray(np.full((96, 128), 20, np.uint8)).save(blank)
    r = run(app, [blank, "--out", tmp_path / "o", *CAMERA])
    lines = error_lines(r)
    assert r.exit_code == 2 and len(lines) == 1
    assert str(blank) in lines[0] and "no stars: 0 star candidates detected" in lines[0]


@pytest.mark.parametrize(("args", "needle"), [
    (["--camera", "nosuch"], "nosuch"),
    (["--set", "camera.focal_length_mm=-3"], "camera.focal_length_mm"),
    (["--set", "stars.enabled=true"], "camera.KEY=VALUE"),
    (["--epoch", "yesterday"], "--epoch"),
    (["--set", "camera.width=640"], "camera.width/height"),
])
def test_bad_options_are_one_line_errors(app, tmp_path, args, needle):
    out = tmp_path / "o"
    r = run(app, [IMAGES[0], "--out", out, *args])
    lines = error_lines(r)
    assert r.exit_code == 2 and lines and needle in lines[0], r.output
    if needle != "camera.width/height":  # refused before any image is read: nothing written
        assert not out.exists()


def test_amie_vega_frame_from_the_command_line(app, tmp_path, monkeypatch):
    """The raw SMART-1 AMIE Vega frame (.IMG) with the amie preset: read, no attitude, the
    one-line verdict "too few stars" with the camera's reach and the counts, exit 2."""
    from starnav.reference.amie.frame import packaged_frame
    from starnav.reference.amie.vega import VEGA_FRAME

    monkeypatch.setenv("STARNAV_CACHE_DIR", str(tmp_path / "cache"))
    r = run(app, [packaged_frame(VEGA_FRAME), "--camera", "amie", "--out", tmp_path / "o"])
    lines = error_lines(r)
    assert r.exit_code == 2 and len(lines) == 1 and "too few stars: the camera reaches V" in \
        lines[0], r.output
    row = json.loads((tmp_path / "o" / "results.json").read_text())["images"][0]
    assert row["epoch_source"] == "PDS label START_TIME"
    assert abs(row["epoch_jyear"] - 2004.23) < 0.01
    assert 3.0 < row["limiting_v"] < 6.0
    assert f"among the {row['n_detections']} detections verified" in row["reason"]


def shell_commands(text: str, start: str) -> list[list[str]]:
    """The shell lines of ``text`` beginning with ``start`` (continuations joined, comments
    dropped), split into words."""
    import shlex

    joined = re.sub(r"\\\n\s*", " ", text)
    return [shlex.split(ln.split("#")[0]) for ln in joined.splitlines()
            if ln.strip().startswith(start)]


def test_the_documented_command_on_the_repository_frames_runs(app, solved, tmp_path,
                                                              monkeypatch):
    """The README's and docs/stars.md's ``starnav stars solve tests/data/stars/*.tiff`` line
    (the same in both), run as written from the repository's root (only ``--out`` moved to a
    temporary directory): both frames solved, exit 0."""
    monkeypatch.setenv("STARNAV_CACHE_DIR", str(tmp_path / "cache"))
    root = DATA.parents[2]
    cmds = [c[c.index("stars"):] for doc in ("README.md", "docs/stars.md")
            for c in shell_commands((root / doc).read_text(encoding="utf-8"),
                                    (".venv/bin/starnav stars solve", "starnav stars solve"))
            if "tests/data/stars/*.tiff" in c]
    assert len(cmds) == 2 and cmds[0] == cmds[1], cmds
    args = cmds[0][2:]
    k = args.index("--out")
    args[k + 1] = str(tmp_path / "o")
    files = sorted(root.glob("tests/data/stars/*.tiff"))
    assert [f.name for f in files] == sorted(REF)
    i = args.index("tests/data/stars/*.tiff")
    r = run(app, [*args[:i], *files, *args[i + 1:]])
    assert r.exit_code == 0, r.output
    rows = json.loads((tmp_path / "o" / "results.json").read_text())["images"]
    assert [x["status"] for x in rows] == ["ok", "ok"]
