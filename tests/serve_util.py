"""Shared by the Python script tests: waiting for `tessera serve` / `tessera-server serve` to listen."""
import re
import threading

LISTENING = re.compile(r'"msg":"listening","grpc":"(?:[^"]*:)?(\d*)","http":"(?:[^"]*:)?(\d*)"')


def wait_listening(p, lines=None):
    """Reads the server's stderr (JSON log lines) until it listens; returns (grpc port, http port),
    0 for a listener that is off, or None when it exits first. After that a thread keeps draining
    stderr, so a chatty server never blocks on a full pipe. `lines` collects what was read."""
    for line in p.stderr:
        if lines is not None:
            lines.append(line)
        m = LISTENING.search(line)
        if m:
            threading.Thread(target=lambda: [None for _ in p.stderr], daemon=True).start()
            return int(m.group(1) or 0), int(m.group(2) or 0)
    return None
