"""A run drawn live in Meshcat, and its recording saved as a self-contained HTML replay.

:func:`simulate_live` starts a Meshcat server bound to 127.0.0.1 (no network beyond the
loopback unless another host is asked for), builds the scenario with its live view
(:func:`stt_drake.assembly.diagram.add_live_view`: the
:class:`~stt_drake.systems.visualizer.TubeVisualizer` for the tube, the obstacles and their
ε / p_d level sets, Drake's ``MeshcatVisualizer`` for the FR3 arm), and simulates while
Meshcat records (``StartRecording``). After the run, ``StopRecording`` /
``PublishRecording`` turn the recording into Meshcat's animation (its time slider is the
replay's time display) and ``Meshcat.StaticHtml()`` is saved: one HTML file that plays the
run in a browser, offline.
"""

from __future__ import annotations

from pathlib import Path

from pydrake.geometry import Meshcat, MeshcatParams

from stt_drake.config import Scenario
from stt_drake.run import RunResult, simulate
from stt_drake.systems.visualizer import PUBLISH_PERIOD

#: Where the live view's Meshcat server listens unless told otherwise: the loopback only.
LOCALHOST = "127.0.0.1"


class MeshcatHostError(ValueError):
    """No Meshcat server can listen on the host asked for (not an address of this
    machine, not a host name that resolves to one)."""


def start_meshcat(host: str = LOCALHOST) -> Meshcat:
    """A Meshcat server on `host` (default the loopback interface, never the network unless
    asked: pydrake's own default is every interface) at an ephemeral port, so parallel
    runs never collide.

    Raises:
        MeshcatHostError: the server cannot listen there (binding fails locally: nothing
            is sent anywhere).
    """
    try:
        return Meshcat(MeshcatParams(host=host, port=0))
    except RuntimeError as error:  # Drake: "Meshcat failed to open a websocket port."
        raise MeshcatHostError(
            f"cannot open a Meshcat server on {host!r} ({str(error).strip()}): give an address "
            f"of this machine ({LOCALHOST}, the default, or '*' for every interface)"
        ) from None


def simulate_live(
    scenario: Scenario,
    path: str | Path,
    strict: bool | None = None,
    host: str = LOCALHOST,
    meshcat: Meshcat | None = None,
    announce: bool = False,
) -> tuple[RunResult, Path]:
    """Simulate `scenario` drawn live in Meshcat and save the recording as HTML.

    Args:
        scenario: the run (as for :func:`stt_drake.run.simulate`).
        path: the HTML replay to write (its folder is created).
        strict: as for :func:`stt_drake.run.simulate`.
        host: the interface a new Meshcat server listens on (default :data:`LOCALHOST`;
            ``"*"``: every interface); ignored when `meshcat` is given.
        meshcat: draw into this Meshcat instead of a new one (its scene is cleared).
        announce: print the live view's URL before simulating.

    Returns:
        The run's result and the path written.
    """
    meshcat = start_meshcat(host) if meshcat is None else meshcat
    meshcat.Delete()
    meshcat.DeleteAddedControls()
    meshcat.DeleteRecording()
    if announce:
        print(f"live view: {meshcat.web_url()}", flush=True)
    meshcat.StartRecording(frames_per_second=1.0 / PUBLISH_PERIOD)
    try:
        result = simulate(scenario, strict, meshcat=meshcat)
    finally:
        meshcat.StopRecording()
    meshcat.PublishRecording()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(meshcat.StaticHtml())
    return result, path
