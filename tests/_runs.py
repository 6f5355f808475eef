"""Helpers shared by the tests that kill and resume runs."""

import json
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
