"""jaml as a package: the wheel ships both packages and assets/, installs offline, and works."""

import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import venv
from pathlib import Path

import pytest

# One of the default suite's longest modules: scheduled early (tests/conftest.py).
pytestmark = pytest.mark.first
ROOT = Path(__file__).resolve().parents[1]
_SOURCES = ("jaml", "envs_mjx", "assets", "pyproject.toml", "README.md", "LICENSE")


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_the_listed_packages_are_the_folders_with_an_init():
    """pyproject lists its packages (assets/ maps to envs_mjx.assets): none may be missing."""
    listed = set(_pyproject()["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts)
             for top in ("jaml", "envs_mjx") for p in (ROOT / top).rglob("__init__.py")}
    assert listed - {"envs_mjx.assets"} == found


def test_license_is_apache_and_citation_names_the_paper():
    text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in text and "Version 2.0, January 2004" in text
    assert "END OF TERMS AND CONDITIONS" in text
    assert _pyproject()["project"]["license"] == {"text": "Apache-2.0"}
    cff = (ROOT / "CITATION.cff").read_text()
    assert "Analytic Manifold Learning: Unifying & Evaluating Representations" in cff
    assert "Antonova" in cff and "Hofmann" in cff


def _pins() -> dict[str, str]:
    """constraints.txt: canonical name → the exact version `make install` installs."""
    from packaging.utils import canonicalize_name

    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"constraints.txt: {line!r} is not NAME==VERSION"
            pins[canonicalize_name(name)] = version
    return pins


def test_requirements_are_ranges_that_admit_the_pins_and_a_gpu_hosts_jax_0_11_2():
    """The wheel installs into an environment with its own JAX: every requirement (extras
    included) is a range, not a pin, and admits the version constraints.txt pins; jax and
    jaxlib admit 0.11.2 (a GPU host's jax[cuda13]) and 0.10.2 (the pins), and so does the
    `cuda` extra; `make install` installs with the constraints."""
    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    project, pins = _pyproject()["project"], _pins()
    extras = project["optional-dependencies"]
    requirements = [Requirement(r) for r in project["dependencies"]]
    requirements += [Requirement(r) for group in extras.values() for r in group]
    for r in requirements:
        name = canonicalize_name(r.name)
        assert name in pins, f"{r} has no pin in constraints.txt"
        assert r.specifier.contains(pins[name]), f"{r} does not admit the pin {pins[name]}"
        assert not any(s.operator in ("==", "===") for s in r.specifier), f"{r} is a pin"
    by_name = {canonicalize_name(r.name): r for r in map(Requirement, project["dependencies"])}
    (cuda,) = map(Requirement, extras["cuda"])
    assert cuda.name == "jax" and cuda.extras == {"cuda12"}
    for r in (by_name["jax"], by_name["jaxlib"], cuda):
        assert r.specifier.contains("0.11.2") and r.specifier.contains("0.10.2"), r
    assert cuda.specifier == by_name["jax"].specifier
    assert pins["jax"] == pins["jaxlib"]
    makefile = (ROOT / "Makefile").read_text()
    assert "-c constraints.txt -e '.[$(EXTRAS)]'" in makefile
    assert "$(STAMP): pyproject.toml constraints.txt" in makefile


_OUTSIDE = """
import hashlib, jax, numpy as np, envs_mjx, jaml
from envs_mjx.domains._assets import ASSETS
pixels = np.asarray(envs_mjx.make("CartPole").reset(jax.random.PRNGKey(3)).pixels)
print(jaml.__file__, envs_mjx.__file__, ASSETS, pixels.shape == (64, 64, 3), pixels.std() > 0,
      hashlib.sha256(pixels.tobytes()).hexdigest(), sep="|")
"""


def test_wheel_installs_offline_and_renders_from_outside_the_checkout(tmp_path):
    """Build the wheel (no network, this venv's setuptools), install it into a fresh venv with
    `--no-index`, and from a folder outside the checkout make CartPole and render its first
    frame: the same frame as the checkout's.

    The checkout's process starts first, beside the build, and writes its programs to a
    compilation cache the installed one then reads: one compile of the frame's program, not
    two racing on the CI's two cores (the cache key leaves out source paths; a program that
    differed, e.g. from other assets, would miss it and compile)."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "XLA_FLAGS")}
    env |= {"JAX_COMPILATION_CACHE_DIR": str(tmp_path / "xla-cache"),
            "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
            "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0"}
    # The same script from the checkout (in its own process, so both compile alike).
    clone_proc = subprocess.Popen([sys.executable, "-c", _OUTSIDE], cwd=ROOT,
                                  env=env | {"PYTHONPATH": str(ROOT)}, text=True,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    src = tmp_path / "src"
    for name in _SOURCES:
        copy = shutil.copytree if (ROOT / name).is_dir() else shutil.copy
        copy(ROOT / name, src / name, **({"ignore": shutil.ignore_patterns("__pycache__")}
                                         if (ROOT / name).is_dir() else {}))
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps",
                    "--no-build-isolation", "--no-index", "-w", wheels, src], check=True)
    (wheel,) = wheels.glob("jaml-*.whl")
    target = tmp_path / "venv"
    venv.create(target, with_pip=False)
    python = target / "bin" / "python"
    # The dependencies: this interpreter's site-packages, after the fresh venv's own.
    site = subprocess.run([python, "-c", "import site; print(site.getsitepackages()[0])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    subprocess.run([sys.executable, "-m", "pip", "--python", python, "install", "--quiet",
                    "--no-index", "--no-deps", wheel], check=True, env=env)
    # Written after the install, so that pip does not see this venv's own jaml as installed.
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    Path(site, "jaml_test_deps.pth").write_text("\n".join(sorted(deps)) + "\n")
    clone_out = clone_proc.communicate()  # its programs cached before the installed one runs
    installed_proc = subprocess.Popen([python, "-c", _OUTSIDE], cwd=tmp_path, env=env, text=True,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    procs = [installed_proc, clone_proc]
    outs = [installed_proc.communicate(), clone_out]
    for p, (_, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-2000:]
    installed, clone = (out.strip().splitlines()[-1].split("|") for out, _ in outs)
    assert installed[:3] == [str(Path(site) / "jaml" / "__init__.py"),
                             str(Path(site) / "envs_mjx" / "__init__.py"),
                             str(Path(site) / "envs_mjx" / "assets")]
    assert clone[2] == str(ROOT / "assets")
    assert installed[3:5] == ["True", "True"]  # a 64x64 rendering, not a blank placeholder
    assert installed[5] == clone[5]
    (entry_points,) = Path(site).glob("jaml-*.dist-info/entry_points.txt")
    assert "jaml = jaml._launch:main" in entry_points.read_text()
    assert (target / "bin" / "jaml").is_file()


@pytest.mark.parametrize("name", ["cartpole.xml", "meshes/duck/textured.obj",
                                  "textures/clay.png"])
def test_package_data_globs_cover_the_assets_the_domains_read(name):
    """Every kind of file the domains open is matched by the wheel's package-data globs."""
    import fnmatch

    globs = _pyproject()["tool"]["setuptools"]["package-data"]["envs_mjx.assets"]
    assert (ROOT / "assets" / name).is_file()
    assert any(fnmatch.fnmatch(name, g.replace("**/", "*")) for g in globs)
