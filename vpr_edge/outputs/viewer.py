"""The Rerun Viewer that ``localize --view`` shows a stream in: one already listening on the port is used as it
is; otherwise one is started, detached (it stays open after the stream ends), with its usage analytics off.

Rerun's SDK, which vpr-edge runs in its own process, sends nothing; its Viewer sends anonymous usage analytics
unless its configuration file says ``analytics_enabled: false`` (what ``rerun analytics disable`` writes; Rerun
has no switch in the environment). A vehicle sends nothing anywhere, and vpr-edge does not change a user's own
Rerun settings: the Viewer it starts reads its configuration and data from a folder of vpr-edge's own
(``viewer_home``), whose configuration has analytics off."""
from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from vpr_edge.errors import InputError

PORT = 9876            # Rerun's default Viewer port
READY_S = 20.0         # how long a starting Viewer is waited for


def viewer_home() -> Path:
    """vpr-edge's folder for the Viewer it starts (``$XDG_CACHE_HOME/vpr-edge/rerun-viewer``, by default under
    ``~/.cache``; a temporary folder where that cannot be made), its analytics configuration written."""
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "vpr-edge" / "rerun-viewer"
    try:
        (base / "config" / "rerun").mkdir(parents=True, exist_ok=True)
    except OSError:
        base = Path(tempfile.mkdtemp(prefix="vpr-edge-rerun-viewer."))
        (base / "config" / "rerun").mkdir(parents=True)
    config = base / "config" / "rerun" / "analytics.json"
    data = base / "data" / "rerun" / "analytics"
    doc = {"analytics_enabled": False, "analytics_id": "vpr-edge", "metadata": {},
           "config_file_path": str(config), "data_dir_path": str(data)}
    text = json.dumps(doc)
    if not config.is_file() or config.read_text() != text:
        config.write_text(text)
    return base


def viewer_env(home: Path) -> dict[str, str]:
    """The environment the Viewer is started with: this one, with its configuration and data in ``home``."""
    return dict(os.environ, XDG_CONFIG_HOME=str(home / "config"), XDG_DATA_HOME=str(home / "data"),
                RERUN_APP_ONLY="true")


def viewer_binary() -> str:
    """The Rerun Viewer executable installed with rerun-sdk (its ``rerun_cli`` package), else ``rerun`` on
    PATH; InputError when there is none."""
    import importlib.util

    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin:
        exe = Path(spec.origin).parent / ("rerun.exe" if sys.platform.startswith("win") else "rerun")
        if exe.is_file():
            return str(exe)
    found = shutil.which("rerun")
    if found is None:
        raise InputError("{opt.view}: the Rerun Viewer (rerun) is not installed: pip install 'vpr-edge[view]'")
    return found


def listening(port: int, host: str = "127.0.0.1") -> bool:
    """Whether something accepts connections on ``host:port``."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.2)
        return s.connect_ex((host, port)) == 0


def start_viewer(port: int = PORT, extra: list[str] | None = None) -> str:
    """The gRPC address of a local Viewer on ``port``: the one listening there, else one started (detached,
    analytics off: ``viewer_home``) and waited for. ``extra``: more arguments for a started Viewer."""
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    if listening(port):
        return url
    argv = [viewer_binary(), "--port", str(port), "--hide-welcome-screen", "--expect-data-soon", *(extra or [])]
    try:
        viewer = subprocess.Popen(argv, env=viewer_env(viewer_home()), stdin=subprocess.DEVNULL,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    except OSError as e:
        raise InputError("{opt.view}: cannot start the Rerun Viewer {exe} ({why})", exe=argv[0],
                         why=e.strerror or e) from None
    deadline = time.monotonic() + READY_S
    while not listening(port):
        if viewer.poll() is not None:
            raise InputError("{opt.view}: the Rerun Viewer exited at start (status {status}; no display? record "
                             "with {opt.rerun} FILE.rrd and open it where there is one)", status=viewer.returncode)
        if time.monotonic() > deadline:
            raise InputError("{opt.view}: the Rerun Viewer did not listen on port {port} within {s:.0f} s",
                             port=port, s=READY_S)
        time.sleep(0.1)
    return url
