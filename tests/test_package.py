"""The package as a user gets it: shipped scenes by name, node types from other
installed packages (the `dockhil.nodes` entry points), and the wheel itself,
installed into a fresh venv and run from another directory."""

from __future__ import annotations

import ast
import os
import re
import site
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

from dockhil import node_types
from dockhil.analysis.sweep import CampaignError, load_campaign
from dockhil.errors import LaunchError
from dockhil.scene import launchfile

REPO = Path(__file__).resolve().parent.parent
SCENES = sorted(p.name for p in (REPO / "launch").glob("*.yaml"))


def source_version() -> str:
    """dockhil.__version__ read from the source text, not imported."""
    tree = ast.parse((REPO / "dockhil" / "__init__.py").read_text())
    return next(
        n.value.value for n in tree.body if isinstance(n, ast.Assign) and [t.id for t in n.targets] == ["__version__"]
    )


def see_this_environment(py: Path) -> None:
    """Lets the venv of `py` import what this test's environment has (pip, msgspec, ...).

    A venv made from inside another venv is based on the base interpreter, so its
    --system-site-packages are the base's, not this environment's. A plain path in a .pth file
    adds a directory without running its own .pth files: an editable dockhil installed here
    stays out of sight, and the venv's own site-packages (the wheel) come first."""
    site_dir = subprocess.run(
        [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    ).stdout.strip()
    Path(site_dir, "outer_environment.pth").write_text("\n".join(site.getsitepackages()) + "\n")


def clean_env(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return {**env, **extra}


# -- shipped scenes by name ------------------------------------------------------
def test_a_shipped_scene_is_found_by_name_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert "hil.yaml" in SCENES and "stability.yaml" in SCENES
    for name in ("hil.yaml", "launch/hil.yaml"):
        assert launchfile.find_shipped(name).resolve() == (REPO / "launch" / "hil.yaml").resolve()
    scene = launchfile.load("stability.yaml")
    assert Path(scene.path).resolve() == (REPO / "launch" / "stability.yaml").resolve() and scene.nodes
    # a campaign by name: its shipped scene resolves too
    assert Path(load_campaign("fig7.yaml").scene).name == "stability.yaml"


def test_a_file_in_the_current_directory_wins_over_a_shipped_scene(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "hil.yaml").write_text("nodes: []\n")
    assert launchfile.find_shipped("hil.yaml") == Path("hil.yaml")
    with pytest.raises(LaunchError, match="no node to start"):  # the local file was read, not the shipped one
        launchfile.load("hil.yaml")


@pytest.mark.parametrize("name", ["nope.yaml", "launch/nope.yaml", "../launch/hil.yaml", "/nowhere/hil.yaml"])
def test_a_name_that_is_neither_a_file_nor_shipped_is_one_line_listing_the_scenes(tmp_path, monkeypatch, name):
    (tmp_path / "here").mkdir()
    monkeypatch.chdir(tmp_path / "here")
    with pytest.raises(LaunchError) as err:
        launchfile.load(name)
    message = str(err.value)
    assert "\n" not in message and repr(name) in message and "not found" in message
    if not name.startswith("/"):
        assert message.endswith(f"(shipped: {', '.join(SCENES)})")


def test_an_unknown_campaign_lists_the_shipped_campaigns(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(CampaignError, match=r"'nope\.yaml' not found.*\(shipped: fig7\.yaml\)"):
        load_campaign("nope.yaml")


def test_the_cli_finds_a_shipped_scene_from_another_directory(tmp_path):
    env = clean_env(PYTHONPATH=str(REPO))
    r = subprocess.run(
        [sys.executable, "-m", "dockhil.cli", "graph", "stability.yaml"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert str((REPO / "launch" / "stability.yaml").resolve()) in r.stdout
    r = subprocess.run(
        [sys.executable, "-m", "dockhil.cli", "launch", "nope.yaml", "--duration", "0.1"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "hil.yaml" in r.stderr, r.stderr


# -- node types from other packages ------------------------------------------------
PLUGIN_MODULE = '''
from dockhil.node import Node, Output, Param
from dockhil.msgs import Vector3, Wrench, WrenchStamped


class Ramp(Node):
    """A force ramp on /ramp."""

    outputs = {"out": Output(WrenchStamped, "/ramp")}
    params = {"slope": Param(float, 2.0, unit="N/s", help="force per second")}

    def step(self, tick, inputs):
        return {"out": WrenchStamped(header=tick.header(), wrench=Wrench(force=Vector3(x=self.p.slope * tick.t)))}


class Helper:
    """Not a node."""


class ShadowFt(Ramp):
    """Would replace the built-in ft_sim: must not."""
'''

ENTRY_POINTS = """
[dockhil.nodes]
ramp = dockhil_fake_plugin:Ramp
not_a_node = dockhil_fake_plugin:Helper
missing_module = dockhil_fake_missing:Thing
no_such_class = dockhil_fake_plugin:Nowhere
not_a_path = dockhil_fake_plugin.Ramp
ft_sim = dockhil_fake_plugin:ShadowFt

[console_scripts]
unrelated = dockhil_fake_plugin:Helper
"""


@pytest.fixture
def fake_distribution(tmp_path, monkeypatch):
    """A distribution `dockhil-fake-plugin 1.2` on a sys.path entry, as `pip install` would leave it."""
    site = tmp_path / "site"
    info = site / "dockhil_fake_plugin-1.2.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: dockhil-fake-plugin\nVersion: 1.2\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    (site / "dockhil_fake_plugin.py").write_text(PLUGIN_MODULE)
    monkeypatch.syspath_prepend(str(site))
    yield site
    sys.modules.pop("dockhil_fake_plugin", None)


def test_an_installed_package_adds_a_node_type(fake_distribution):
    assert node_types.plugins()["ramp"] == ("dockhil_fake_plugin:Ramp", "dockhil-fake-plugin 1.2")
    cls = node_types.load("ramp")
    assert cls.__name__ == "Ramp" and cls.__module__ == "dockhil_fake_plugin"


def test_a_built_in_name_is_never_replaced_by_a_package(fake_distribution):
    assert "ft_sim" not in node_types.plugins()
    assert node_types.load("ft_sim").__module__ == "dockhil.nodes.ft_sim"


@pytest.mark.parametrize(
    "name, why",
    [
        ("not_a_node", "is not a dockhil node"),
        ("missing_module", "no module 'dockhil_fake_missing'"),
        ("no_such_class", "defines no class 'Nowhere'"),
        ("not_a_path", "not of the form package.module:Class"),
    ],
)
def test_a_broken_entry_point_is_refused_in_one_line_naming_its_package(fake_distribution, name, why):
    with pytest.raises(LaunchError) as err:
        node_types.load(name)
    message = str(err.value)
    assert "\n" not in message and why in message and "dockhil-fake-plugin 1.2" in message
    # ... and the built-in types still load
    assert node_types.load("satellite_dynamics").__name__ == "SatelliteDynamics"


def test_an_unknown_name_lists_the_installed_types_too(fake_distribution):
    with pytest.raises(
        LaunchError,
        match=r"unknown node type 'rampp'; did you mean 'ramp'\? "
        r"\(known types: .*\bramp\b.*satellite_dynamics",
    ):
        node_types.load("rampp")


def test_node_types_lists_packages_and_a_launch_file_runs_their_node(fake_distribution, tmp_path):
    env = clean_env(PYTHONPATH=os.pathsep.join([str(fake_distribution), str(REPO)]))
    r = subprocess.run(
        [sys.executable, "-m", "dockhil.cli", "node", "types"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 1  # the broken entry points are errors ...
    listed = dict(line.split(": ", 1) for line in r.stdout.splitlines())
    assert set(node_types.REGISTRY) < set(listed)  # ... that hide no other type
    assert listed["ramp"] == "A force ramp on /ramp.  [from dockhil-fake-plugin 1.2]"
    errors = r.stderr.strip().splitlines()
    assert len(errors) == 4 and all("dockhil-fake-plugin 1.2" in e for e in errors), r.stderr

    scene = tmp_path / "ramp.yaml"
    scene.write_text(
        textwrap.dedent("""\
        rate: 100
        nodes:
          - name: ramp
            node: ramp
            params: {slope: 3.0}
        """)
    )
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "dockhil.cli",
            "launch",
            "ramp.yaml",
            "--duration",
            "0.1",
            "--composed",
            "--quiet",
            "--bag",
            "ramp.mcap",
        ],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    from dockhil.bags.reader import BagReader

    with BagReader(tmp_path / "ramp.mcap") as bag:
        forces = [(m.header.stamp, m.wrench.force.x) for m in (b.decode() for b in bag.messages(["/ramp"]))]
    assert forces and all(x == pytest.approx(3.0 * t) for t, x in forces)


# -- the wheel ------------------------------------------------------------------
def source_packages() -> set[str]:
    """Every package directory of the source tree, as a wheel path."""
    found = set()
    for top, installed in (("dockhil", "dockhil"),):
        for init in (REPO / top).rglob("__init__.py"):
            if "__pycache__" not in init.parts:
                rel = init.parent.relative_to(REPO / top).as_posix()
                found.add(installed if rel == "." else f"{installed}/{rel}")
    return found


def arithmetic(names: set[str]) -> str:
    """What `dockhil --version` must name for a wheel holding `names`: the compiled twins, which pip
    builds where a C compiler is, or pure Python and why."""
    if os.environ.get("DOCKHIL_PURE_PYTHON"):
        return "pure Python: DOCKHIL_PURE_PYTHON is set"
    built = {n.split(".")[0] for n in names if n.endswith(".so")}
    if built == {"dockhil/contact/_rigid", "dockhil/runtime/_screen"}:
        return "compiled: rigid-body arithmetic, message screen"
    assert not built, built  # one C file built and not the other: say what the compiler said
    return "pure Python: the C twins were not built; install a C compiler and reinstall for speed"


def test_the_wheel_installs_into_a_fresh_venv_and_runs_from_another_directory(tmp_path):
    version = source_version()
    dist = tmp_path / "dist"
    r = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(dist), str(REPO)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    wheel = next(dist.glob("dockhil-*.whl"))
    assert wheel.name.startswith(f"dockhil-{version}-")

    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        info = f"dockhil-{version}.dist-info"
        metadata = z.read(f"{info}/METADATA").decode()
        license_text = z.read(f"{info}/licenses/LICENSE")
        top_level = z.read(f"{info}/top_level.txt").decode().split()
    assert {os.path.dirname(n) for n in names if n.endswith("/__init__.py")} == source_packages()
    assert {f"dockhil/launch/{s}" for s in SCENES} <= names and "dockhil/launch/campaigns/fig7.yaml" in names
    assert "dockhil/py.typed" in names
    assert license_text == (REPO / "LICENSE").read_bytes()
    assert re.search(rf"^Version: {re.escape(version)}$", metadata, re.M)
    assert re.search(r"^License-Expression: Apache-2.0$", metadata, re.M)
    assert not any(n.startswith(("tests/", "bench/", "launch/", "msgs/", "nodes/")) for n in names)
    assert top_level == ["dockhil"]  # msgs and nodes are PyPI projects of their own: never top-level here

    venv = tmp_path / "venv"
    # Without a pip of its own (copying one in is most of a venv's cost): the venv's python runs the
    # pip it sees through the system site-packages, which installs into the venv.
    subprocess.run(
        [sys.executable, "-m", "venv", "--without-pip", "--system-site-packages", str(venv)], check=True, timeout=120
    )
    py, exe = venv / "bin" / "python", venv / "bin" / "dockhil"
    see_this_environment(py)
    subprocess.run(
        [str(py), "-m", "pip", "install", "-q", "--no-deps", str(wheel)], check=True, timeout=300, env=clean_env()
    )
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()

    def run(*argv, timeout=120):
        return subprocess.run(
            [str(exe), *argv], cwd=elsewhere, env=clean_env(), capture_output=True, text=True, timeout=timeout
        )

    where = subprocess.run(
        [
            str(py),
            "-c",
            "import dockhil, dockhil.node_types, dockhil.msgs; from dockhil.scene import launchfile; "
            "print(dockhil.__file__, dockhil.node_types.__file__, dockhil.msgs.__file__, launchfile.SHIPPED_SCENES)",
        ],
        cwd=elsewhere,
        env=clean_env(),
        capture_output=True,
        text=True,
        timeout=60,
    )
    site = str(venv / "lib")
    assert where.returncode == 0 and all(p.startswith(site) for p in where.stdout.split()), where.stdout
    r = run("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"dockhil {version} ({arithmetic(names)})"
    r = run("launch", "hil.yaml", "--composed", "--duration", "0.5", "--quiet", "--bag", "hil.mcap")
    assert r.returncode == 0, r.stderr
    assert (elsewhere / "hil.mcap").stat().st_size > 0
    r = run("graph", "stability.yaml")
    assert r.returncode == 0 and str(venv) in r.stdout.splitlines()[0], r.stdout + r.stderr
    r = run("report", "--quick", timeout=240)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert (elsewhere / "report" / "report.json").stat().st_size > 0
