"""The viewer in a Jupyter notebook: an anywidget (`pip install 'aquarium-warp[notebook]'`) that shows
the page of an attached viewer (`attach`) in the cell's output.

```python
from aquarium_warp.viewer.widget import ViewerWidget

view = ViewerWidget(env)      # serves env (attach) and shows its page below the cell
view                          # the cell's output; step env in later cells, the view follows
view.close()
```

The page is loaded from the viewer's server by the notebook's browser, so that browser must reach it:
the default host 127.0.0.1 works where Jupyter runs on the same machine; for a remote kernel forward the
port (`ssh -L`) or give `host`.
"""

from __future__ import annotations

import anywidget
import traitlets

from .attached import attach

_ESM = """
export default {
  render({ model, el }) {
    const frame = document.createElement("iframe");
    frame.title = "Aquarium viewer";
    frame.style.border = "0";
    frame.style.width = "100%";
    const update = () => { frame.src = model.get("url"); frame.style.height = `${model.get("height")}px`; };
    update();
    model.on("change:url", update);
    model.on("change:height", update);
    el.appendChild(frame);
  },
};
"""


class ViewerWidget(anywidget.AnyWidget):
    """The live page of `env` (served by `attach(env, **options)`) as a notebook widget. Synced state:
    `url` (the page) and `height` (px)."""

    _esm = _ESM
    url = traitlets.Unicode("").tag(sync=True)
    height = traitlets.Int(640).tag(sync=True)
    attached = None  # the `attached.Attached` viewer it shows

    def __init__(self, env, *, height: int = 640, **options):
        if isinstance(height, bool) or not isinstance(height, int) or not 200 <= height <= 4000:
            raise ValueError(f"height={height!r} must be an integer in [200, 4000] (px)")
        self.attached = attach(env, **options)
        super().__init__(url=self.attached.url, height=height)

    def close(self) -> None:
        """Stop serving and close the widget."""
        if self.attached is not None:
            self.attached.close()
        super().close()
