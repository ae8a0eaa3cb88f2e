"""Foxglove layouts for a joint: which panel shows what, as a file Foxglove imports.

``admittance/data/foxglove/session-layout.json`` reads a ``session.mcap`` (topic ``/joint1/cycle``) and
``admittance/data/foxglove/live-layout.json`` the live view (topic ``/admittance/joint1``); both are made
by :func:`layout` (tests/test_foxglove_view.py checks the shipped files against it). In Foxglove:
Layouts, "Import from file". For another joint, replace ``joint1`` in the file.

Panels, top to bottom: force (N) and torque (N·m); model, goal and present angle (rad); the
rendering error theta_present − theta_model (rad); and, for a recording, the parameter changes
and the loop statistics as raw messages.
"""

from __future__ import annotations

from pathlib import Path

LAYOUTS = {"session-layout.json": ("/joint1/cycle", True), "live-layout.json": ("/admittance/joint1", False)}


def layout(topic: str, recording: bool) -> str:
    from foxglove import layouts as fl

    def plot(title: str, *series: tuple[str, str]):
        paths = [fl.PlotSeries(value=f"{topic}.{field}", label=label) for field, label in series]
        return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=paths, show_legend=True))

    rows = [plot("force (N) and torque (N·m)", ("force", "force N"), ("tau", "tau N·m")),
            plot("angles (rad)", ("theta_model", "model"), ("theta_goal", "goal"), ("theta_present", "present")),
            plot("rendering error θ_present − θ_model (rad)", ("rendering_error", "error"))]
    if recording:
        rows.append(fl.SplitContainer(direction="row", items=[
            fl.SplitItem(content=fl.RawMessagesPanel(title="parameter changes",
                                                     config=fl.RawMessagesConfig(topic_path="/params"))),
            fl.SplitItem(content=fl.RawMessagesPanel(title="loop statistics",
                                                     config=fl.RawMessagesConfig(topic_path="/stats")))]))
    content = fl.SplitContainer(direction="column", items=[fl.SplitItem(content=row) for row in rows])
    return fl.Layout(content=content).to_json()


def write_layouts(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, (topic, recording) in LAYOUTS.items():
        (folder / name).write_text(layout(topic, recording) + "\n")


if __name__ == "__main__":  # python -m admittance.daemon.foxglove_layout admittance/data/foxglove
    import sys

    write_layouts(Path(sys.argv[1]))
