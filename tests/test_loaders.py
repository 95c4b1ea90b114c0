"""The one loader of configuration files (``config_base``): YAML and JSON read the same way
(the file named, its size bounded, UTF-8), and scenario and bench mappings validated by one
path (``model_from_mapping``)."""

from __future__ import annotations

import pytest

from starnav.calibration.schema import bench_from_dict
from starnav.camera_calibration import read_calibration
from starnav.config import scenario_from_dict
from starnav.config_base import MAX_CONFIG_BYTES, read_json_file, read_yaml_file
from starnav.errors import ConfigError, DataFileError


def test_json_and_yaml_files_fail_alike(tmp_path):
    good = tmp_path / "a.json"
    good.write_text('{"a": [1, 2]}')
    assert read_json_file(good, "x") == {"a": [1, 2]} == read_yaml_file(good, "x")
    bad = tmp_path / "bad.json"
    bad.write_text('{"a": ')
    with pytest.raises(ConfigError, match=r"calibration file = .*bad\.json.*valid JSON"):
        read_json_file(bad, "calibration file")
    latin = tmp_path / "latin.json"
    latin.write_bytes(b'{"a": "\xe9"}')
    for read in (read_json_file, read_yaml_file):
        with pytest.raises(ConfigError, match="UTF-8"):
            read(latin, "x")
        with pytest.raises(DataFileError, match="is a directory"):
            read(tmp_path, "x")
    big = tmp_path / "big.json"
    big.write_text(" " * (MAX_CONFIG_BYTES + 1))
    with pytest.raises(ConfigError, match="at most"):
        read_json_file(big, "x")
    with pytest.raises(ConfigError, match="valid JSON"):  # a calibration file reads the same
        read_calibration(bad)


def test_scenario_and_bench_mappings_are_validated_by_one_path():
    with pytest.raises(ConfigError, match="<root> = 'list'"):
        scenario_from_dict([1, 2])  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="<bench root> = 'list'"):
        bench_from_dict([1, 2])  # type: ignore[arg-type]
    sc = scenario_from_dict(None, ["seed=5"])  # type: ignore[arg-type]
    assert sc.seed == 5
    with pytest.raises(ConfigError, match="screen.height_mm"):
        bench_from_dict({}, ["screen.height_mm=-1"])
