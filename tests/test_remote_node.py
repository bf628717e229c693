"""A node on another machine: over tcp, started there by the command the launcher prints.
On this machine 127.0.0.2 stands for the other host (all of 127/8 is loopback)."""

import shlex
import subprocess
import sys
import time

from tests.conftest import dockhil_cmd
from tests.support.inprocess import run_main

SCENE = """
rate: 1000
duration: 0.3
nodes:
  - {{name: integ, node: "tests.support.graphnodes:Integrator"}}
  - {{name: gain, node: "tests.support.graphnodes:Gain"{host}}}
  - {{name: trace, node: "tests.support.graphnodes:Trace", params: {{path: "{trace}"}}}}
"""


def test_remote_node_runs_from_the_printed_command_and_changes_no_bit(write_launch, tmp_path):
    local = tmp_path / "local.txt"
    # The reference runs composed, in this process: a graph's processes give a composed run's bits
    # (test_runtime.py holds that), so the graph with its remote node must give them too.
    code, out, err = run_main(
        "launch", write_launch(SCENE.format(host="", trace=local), "local.yaml"), "--quiet", "--composed"
    )
    assert code == 0, out + err

    remote = tmp_path / "remote.txt"
    scene = write_launch(SCENE.format(host=", host: 127.0.0.2", trace=remote), "remote.yaml")
    launch = subprocess.Popen(
        dockhil_cmd("launch", scene, "--quiet"), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    line = launch.stdout.readline()
    assert line.startswith("[launch] node 'gain' runs on 127.0.0.2: copy the key file ")
    key_file = line.split("copy the key file ", 1)[1].split()[0]
    argv = shlex.split(line.split("start it there with: ", 1)[1])
    assert argv[:5] == ["python3", "-m", "dockhil.process", "--keys", key_file]
    spec = argv[-1]
    # It binds only the interface the others reach it by, and no key travels on the command line.
    assert '"endpoint":"tcp://127.0.0.2:' in spec and "secret" not in line
    time.sleep(0.5)  # the other machine's operator is a little slower than the launcher
    node = subprocess.run([sys.executable, *argv[1:]], capture_output=True, text=True, timeout=60)
    assert node.returncode == 0, node.stderr
    out, _ = launch.communicate(timeout=60)
    assert launch.returncode == 0, out
    assert remote.read_text() == local.read_text()


def test_bad_host_is_refused(write_launch):
    scene = write_launch('nodes:\n  - {name: a, node: "tests.support.graphnodes:Source", host: "lab pc"}\n')
    code, _, err = run_main("graph", scene)
    assert code == 2 and "`host` must be a host name or address, got 'lab pc'" in err
