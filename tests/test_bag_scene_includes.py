"""A bag's scene comes from the bag: `dockhil analyze` (and every rebuild of a recorded scene) resolves
includes only among the launch files the bag recorded; an include of anything else is refused in one line
without being opened (a FIFO at that path would hang a reader)."""

from __future__ import annotations

import os
import threading
import time

import pytest

from dockhil.bags.reader import BagReader
from dockhil.bags.writer import BagWriter
from dockhil.errors import LaunchError
from dockhil.scene import provenance
from tests.support.inprocess import run_main
from tests.test_analyze import launched

SCENE = "rate: 100.0\nnodes:\n  - {name: dynamics, node: satellite_dynamics}\ninclude:\n  - file: %s\n"
PART = "nodes:\n  - {name: impedance, node: virtual_impedance}\n"


def fifo(tmp_path) -> str:
    """A FIFO with nobody writing: whoever opens it to read hangs. A guard thread opens it for writing once
    a reader waits, so that a reader that did open it gets an empty file and the test fails, not hangs."""
    path = str(tmp_path / "part.yaml")
    os.mkfifo(path)

    def guard():
        for _ in range(100):
            try:
                os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))  # succeeds only while a reader waits
                return
            except OSError:
                time.sleep(0.1)

    threading.Thread(target=guard, daemon=True).start()
    return path


@pytest.mark.parametrize("include", ["{fifo}", "../../../{fifo}", "/etc/passwd"])
def test_an_include_outside_the_recorded_texts_is_refused_without_opening_it(tmp_path, include):
    path = fifo(tmp_path)
    include = include.format(fifo=path)
    scene = str(tmp_path / "lab" / "scene.yaml")
    run = {"scene": scene, "args": "{}"}
    with pytest.raises(LaunchError) as refused:
        provenance.rebuild(run, {scene: SCENE % include})
    text = str(refused.value)
    assert "\n" not in text and "not among the launch files the scene recorded" in text, text
    assert "passwd" not in text or "root:" not in text  # nothing of what the path holds


def test_an_include_among_the_recorded_texts_rebuilds():
    scene, part = "/lab/scenes/scene.yaml", "/lab/scenes/parts/impedance.yaml"
    rebuilt = provenance.rebuild({"scene": scene, "args": "{}"}, {scene: SCENE % "parts/impedance.yaml", part: PART})
    assert sorted(n.name for n in rebuilt.nodes) == ["dynamics", "impedance"]


def test_analyze_refuses_a_bag_whose_scene_includes_a_file_outside_it(tmp_path):
    from dockhil.bags import runinfo

    bag, _ = launched(tmp_path, "ideal.yaml", "--duration", "0.5", "--composed")
    path = fifo(tmp_path)
    moved = tmp_path / "moved.mcap"
    scene = str(tmp_path / "lab.yaml")
    with BagReader(bag) as reader, BagWriter(moved) as writer:
        run = dict(runinfo.read(reader).run, scene=scene, args="{}")
        runinfo.write_start(writer, run, {scene: SCENE % path})
        for topic, type_name, log_ns, data in reader:
            writer.add_topic(topic, type_name)
            writer.write(topic, log_ns, log_ns, data)
    code, out, err = run_main("analyze", moved)
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
    assert "not among the launch files the scene recorded" in err and path in err, err


def test_a_recorded_loop_file_is_not_read_again_its_values_are_recorded():
    scene = "/lab/scene.yaml"
    text = (
        "args:\n  loop: {default: ''}\n  delay: {default: 0.03}\nnodes:\n"
        "  - {name: delay, node: delay_injector, params: {delay: $(arg delay)}}\n"
    )
    run = {"scene": scene, "args": '{"loop": "/lab/absent/loop.yaml", "delay": 0.0473}'}
    rebuilt = provenance.rebuild(run, {scene: text})
    assert rebuilt.nodes[0].params["delay"] == 0.0473
