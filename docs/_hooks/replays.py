"""mkdocs hook: the replay pages of `docs/replays/`, generated from the viewer's sources.

Each trajectory `docs/replays/NAME.json` (recorded with `viewer.recording.record_trajectory`) becomes the
page `replays/NAME.html` of the site: `viewer.recording.replay_page`, the page that
`aquarium-warp view --replay NAME.json --out NAME.html` writes, with the viewer's current script and style
inline. The repository holds only the trajectories, so the pages cannot drift from the viewer.
"""

from __future__ import annotations

import posixpath

from mkdocs.structure.files import File

from aquarium_warp.viewer.recording import read_trajectory, replay_page

FOLDER = "replays"


def on_files(files, config):
    for trajectory in [f for f in files if posixpath.dirname(f.src_uri) == FOLDER and f.src_uri.endswith(".json")]:
        page = replay_page(read_trajectory(trajectory.abs_src_path))
        files.append(File.generated(config, trajectory.src_uri.removesuffix(".json") + ".html", content=page))
    return files
