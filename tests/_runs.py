"""Helpers shared by the tests that kill and resume runs."""

import json
import signal
import subprocess
import time


def wait_for_generation(run, generation, process):
    """Block until ``run``'s checkpoint reaches ``generation`` (or fail after 300 s)."""
    deadline = time.time() + 300
    checkpoint = run / "checkpoint.json"
    while time.time() < deadline and process.poll() is None:
        try:
            if json.loads(checkpoint.read_text())["state"]["generation"] >= generation:
                return
        except (FileNotFoundError, json.JSONDecodeError, KeyError):
            pass
        time.sleep(0.02)
    raise AssertionError(f"generation {generation} never checkpointed")


def kill_and_resume(command, run, generation, env) -> str:
    """Run ``command --out run``, kill -9 it once ``generation`` is checkpointed, check it
    wrote no model, resume it with ``--resume``; the resumed ``model.json`` text."""
    process = subprocess.Popen(command + ["--out", str(run)], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_for_generation(run, generation, process)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert not (run / "model.json").exists()
    subprocess.run(command + ["--out", str(run), "--resume"], check=True, env=env,
                   capture_output=True)
    return (run / "model.json").read_text()
