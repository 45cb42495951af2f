"""Tests of the configuration loader (lite_vo/config.py): validation, overrides, inheritance,
shipped profiles, and the profiles being part of a non-editable install."""
from __future__ import annotations

import dataclasses
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from lite_vo.config import (VOConfig, build_config, describe, load_profile, parse_override, profile_names,
                            ResolutionConfig, SystemConfig)
from lite_vo.errors import ConfigError, LiteVOError

ROOT = Path(__file__).resolve().parents[1]


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


# ----------------------------------------------------------------------------------------------
# Validation: errors name the key
# ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("text, needle", [
    ("[resolution]\nmap_widht = 320\n", "resolution.map_widht"),
    ("[tracking]\nhuberr = 2.0\n", "tracking.huberr"),
    ("[resolutions]\nmap_width = 320\n", "[resolutions]"),
    ("map_width = 320\n", "[map_width]"),
    ("[resolution]\nmap_width = \"320\"\n", "resolution.map_width"),
    ("[resolution]\nmap_width = 320.0\n", "resolution.map_width"),
    ("[resolution]\nmap_width = true\n", "resolution.map_width"),
    ("[tracking]\nhuber = \"big\"\n", "tracking.huber"),
    ("[tracking]\naffine_brightness = 1\n", "tracking.affine_brightness"),
    ("[resolution]\nmap_width = 8\n", "resolution.map_width"),
    ("[resolution]\nmap_width = 100000\n", "resolution.map_width"),
    ("[tracking]\nmin_good_ratio = 1.5\n", "tracking.min_good_ratio"),
    ("[mapping]\nmin_grad = -1.0\n", "mapping.min_grad"),
    ("[system]\nmode = \"fast\"\n", "system.mode"),
    ("[system]\nmap_every = 0\n", "system.map_every"),
    ("[tracking]\nhuber = nan\n", "tracking.huber"),
    ("[resolution]\ntrack_level = 3\npyramid_levels = 3\n", "resolution.track_level"),
    ("[resolution\nmap_width = 320\n", "not valid TOML"),
])
def test_invalid_profiles_are_errors_naming_the_key(tmp_path, text, needle):
    path = write(tmp_path / "bad.toml", text)
    with pytest.raises(ConfigError) as err:
        load_profile(path)
    msg = str(err.value)
    assert needle in msg and str(path) in msg
    assert "\n" not in msg  # one line for the CLI


def test_error_is_a_lite_vo_error_and_cli_prints_one_line(tmp_path, capsys):
    assert issubclass(ConfigError, LiteVOError)
    from lite_vo.cli.main import main
    bad = write(tmp_path / "bad.toml", "[tracking]\nhuberr = 2.0\n")
    rc = main(["profile", str(tmp_path), "--profiles", str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and "tracking.huberr" in err and len(err.splitlines()) == 1


def test_valid_values_are_converted_and_kept(tmp_path):
    path = write(tmp_path / "ok.toml", "[tracking]\nhuber = 2\n[system]\nseed = 7\nmode = \"realtime\"\n")
    cfg = load_profile(path)
    assert cfg.tracking.huber == 2.0 and isinstance(cfg.tracking.huber, float)
    assert cfg.system.seed == 7 and cfg.system.mode == "realtime"
    assert cfg.name == "ok"
    assert cfg.resolution == ResolutionConfig()  # untouched sections keep their defaults
    # boundaries of a range are valid
    lo = dataclasses.fields(ResolutionConfig)[0].metadata["lo"]
    assert load_profile(path, [f"resolution.map_width={lo}"]).resolution.map_width == lo


def test_configs_are_frozen():
    cfg = load_profile("phone")
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.resolution.map_width = 10  # type: ignore[misc]


def test_every_field_has_doc_and_range_and_a_valid_default():
    from lite_vo.mapping.config import MappingConfig
    from lite_vo.tracking.config import TrackingConfig
    for cls in (ResolutionConfig, SystemConfig, TrackingConfig, MappingConfig):
        for name, default, rng, doc in describe(cls):
            assert doc, f"{cls.__name__}.{name} has no doc line"
            assert rng, f"{cls.__name__}.{name} has no range"
    # the defaults themselves pass validation
    default = VOConfig()
    data = {k: v for k, v in default.to_dict().items() if k != "name"}
    assert build_config(data).to_dict() | {"name": "default"} == default.to_dict()


# ----------------------------------------------------------------------------------------------
# Overrides
# ----------------------------------------------------------------------------------------------

def test_parse_override_values_in_toml_syntax():
    assert parse_override("tracking.huber=2.5") == ("tracking", "huber", 2.5)
    assert parse_override(" system.map_every = 3 ") == ("system", "map_every", 3)
    assert parse_override("tracking.affine_brightness=true") == ("tracking", "affine_brightness", True)
    assert parse_override('system.mode="realtime"') == ("system", "mode", "realtime")
    assert parse_override("system.mode=realtime") == ("system", "mode", "realtime")  # bare word
    assert parse_override("tracking.converge_eps=1e-6") == ("tracking", "converge_eps", 1e-6)
    for bad in ("tracking.huber", "huber=2", "a.b.c=1", ".huber=1", "tracking.=1"):
        with pytest.raises(ConfigError, match="section.key=value"):
            parse_override(bad)


def test_overrides_apply_on_top_of_profiles_and_are_validated():
    cfg = load_profile("phone", ["resolution.map_width=256", "system.mode=realtime", "tracking.huber=3"])
    assert cfg.resolution.map_width == 256 and cfg.system.mode == "realtime" and cfg.tracking.huber == 3.0
    assert cfg.resolution.track_level == 1  # rest of the profile kept
    with pytest.raises(ConfigError, match="tracking.hubr"):
        load_profile("phone", ["tracking.hubr=3"])
    with pytest.raises(ConfigError, match=r"\[track\]"):
        load_profile("phone", ["track.huber=3"])
    with pytest.raises(ConfigError, match="system.map_every"):
        load_profile("phone", ["system.map_every=0"])
    with pytest.raises(ConfigError, match="resolution.map_width"):
        load_profile("phone", ["resolution.map_width=big"])
    # later overrides win
    assert load_profile("phone", ["system.seed=1", "system.seed=2"]).system.seed == 2
    # loading again is not affected by earlier overrides
    assert load_profile("phone").resolution.map_width == 320


# ----------------------------------------------------------------------------------------------
# Inheritance
# ----------------------------------------------------------------------------------------------

def test_base_inheritance_from_shipped_and_relative_files(tmp_path):
    child = write(tmp_path / "child.toml", 'base = "phone"\n[tracking]\nhuber = 2.0\n')
    cfg = load_profile(child)
    assert cfg.tracking.huber == 2.0 and cfg.resolution.map_width == 320 and cfg.system.map_every_startup == 4
    assert cfg.name == "child"
    # a base given as a file next to the child; values of the same section merge key by key
    write(tmp_path / "parent.toml", "[resolution]\nmap_width = 480\ntrack_level = 2\n")
    grandchild = write(tmp_path / "gc.toml", 'base = "parent.toml"\n[resolution]\ntrack_level = 0\n')
    cfg = load_profile(grandchild)
    assert (cfg.resolution.map_width, cfg.resolution.track_level) == (480, 0)
    # a chain of three
    write(tmp_path / "ggc.toml", 'base = "gc.toml"\n[system]\nseed = 5\n')
    cfg = load_profile(tmp_path / "ggc.toml")
    assert (cfg.resolution.map_width, cfg.resolution.track_level, cfg.system.seed) == (480, 0, 5)


def test_base_errors(tmp_path):
    write(tmp_path / "a.toml", 'base = "b.toml"\n')
    write(tmp_path / "b.toml", 'base = "a.toml"\n')
    with pytest.raises(ConfigError, match="loop"):
        load_profile(tmp_path / "a.toml")
    with pytest.raises(ConfigError, match="nosuchprofile"):
        load_profile(write(tmp_path / "c.toml", 'base = "nosuchprofile"\n'))
    with pytest.raises(ConfigError, match="base"):
        load_profile(write(tmp_path / "d.toml", "base = 3\n"))
    # an inherited invalid value is reported
    write(tmp_path / "badparent.toml", "[tracking]\nhuber = -1.0\n")
    with pytest.raises(ConfigError, match="tracking.huber"):
        load_profile(write(tmp_path / "e.toml", 'base = "badparent.toml"\n'))


def test_unknown_profile_lists_the_available_ones(tmp_path):
    with pytest.raises(ConfigError, match="phone") as err:
        load_profile("no_such_profile")
    assert "no_such_profile" in str(err.value)
    with pytest.raises(ConfigError, match="not found"):
        load_profile(tmp_path / "missing.toml")


# ----------------------------------------------------------------------------------------------
# Shipped profiles
# ----------------------------------------------------------------------------------------------

def test_every_shipped_profile_loads():
    names = profile_names()
    files = sorted(p.stem for p in (ROOT / "profiles").glob("*.toml"))
    assert names == files
    assert {"phone", "desktop", "board", "m640_t320", "m320_t320", "m160_t160", "m160_t80"} <= set(names)
    for n in names:
        cfg = load_profile(n)
        assert cfg.name == n
        assert cfg.resolution.track_level < cfg.resolution.pyramid_levels


def test_default_profile_is_phone():
    assert load_profile() == load_profile("phone")


# ----------------------------------------------------------------------------------------------
# Non-editable install: the profiles are package data of lite_vo.profiles
# ----------------------------------------------------------------------------------------------

def _copy_project(dst: Path) -> Path:
    dst.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "build", "dist", ".venv", "*.pyc", "*.nbi",
                                    "*.nbc", "lite_vo_out")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, dst / name)
    for name in ("lite_vo", "profiles", "ar_demo"):
        shutil.copytree(ROOT / name, dst / name, ignore=ignore)
    return dst


def test_profiles_are_installed_as_package_data(tmp_path):
    """What a wheel contains is what ``build_py`` puts into the build folder (no wheel package needed)."""
    pytest.importorskip("setuptools")
    src = _copy_project(tmp_path / "src")
    lib = tmp_path / "lib"
    proc = subprocess.run([sys.executable, "-c", "from setuptools import setup; setup()", "-q", "build_py",
                           "--build-lib", str(lib)], cwd=src, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    shipped = sorted(p.name for p in (ROOT / "profiles").glob("*.toml"))
    installed = sorted(p.name for p in (lib / "lite_vo" / "profiles").glob("*.toml"))
    assert installed == shipped
    assert (lib / "lite_vo" / "profiles" / "__init__.py").is_file()
    # and the loader finds them there, outside the source tree
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import lite_vo.config as c; "
            "assert c.__file__.startswith(sys.argv[1]), c.__file__; "
            "print(','.join(c.profile_names())); print(c.load_profile('board').system.map_every)")
    proc = subprocess.run([sys.executable, "-I", "-c", code, str(lib)], cwd=tmp_path, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    names, map_every = proc.stdout.split()
    assert names.split(",") == [n[:-5] for n in shipped] and map_every == "4"


def test_wheel_contains_the_profiles(tmp_path):
    pytest.importorskip("wheel", reason="the 'wheel' package is not installed (setuptools < 70 needs it)")
    src = _copy_project(tmp_path / "src")
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                           "-w", str(tmp_path / "dist"), str(src)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    import zipfile
    (whl,) = (tmp_path / "dist").glob("lite_vo-*.whl")
    names = zipfile.ZipFile(whl).namelist()
    for p in (ROOT / "profiles").glob("*.toml"):
        assert f"lite_vo/profiles/{p.name}" in names


def test_user_file_may_extend_the_shipped_profile_of_the_same_name(tmp_path):
    own = tmp_path / "phone.toml"
    own.write_text('base = "phone"\n[system]\nseed = 3\n', encoding="utf-8")
    cfg = load_profile(own)
    assert cfg.system.seed == 3 and cfg.resolution.map_width == 320
