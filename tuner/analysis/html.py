"""The HTML summary of an analysis (Jupyter): its checks and thumbnails of its step response and Bode plot."""

from __future__ import annotations

import base64
import logging
from typing import Any

from ..text import _CSS, _checks_table, _e, _loop_kind, _verdict_html

__all__ = ["analysis_html", "figures_html"]

log = logging.getLogger(__name__)


def figures_html(obj: Any) -> str:
    """Step response and Bode plot as small PNG images (drawn by tuner.analysis.plots, no pyplot)."""
    try:
        from .plots import figure, figure_bytes

        imgs = []
        for kind in ("step", "bode"):
            fig = figure(obj, kind)
            fig.set_size_inches(5.0, 3.8)
            data = base64.b64encode(figure_bytes(fig, fmt="png", dpi=64)).decode()
            imgs.append(f'<img alt="{kind}" style="max-width:340px;margin-right:6px" '
                        f'src="data:image/png;base64,{data}"/>')
        return "<div>" + "".join(imgs) + "</div>"
    except Exception as e:  # a display must not raise: the tables stand without the pictures
        log.warning("thumbnails not drawn: %s", e)
        return f"<p><i>(plots not drawn: {_e(type(e).__name__)})</i></p>"



def analysis_html(a: Any, *, thumbnails: bool = True) -> str:
    """The HTML summary of an :class:`~tuner.analysis.Analysis` (Jupyter): checks, thumbnails."""
    head = f"<b>Analysis</b> {_e(_loop_kind(a))}: {_verdict_html([a])}"
    pics = figures_html(a) if thumbnails else ""
    return f'{_CSS}<div class="tuner-r"><p>{head}</p>{_checks_table([a])}{pics}</div>'
