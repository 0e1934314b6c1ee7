"""Views of recorded twin bags: :mod:`.bag_view` extracts what to draw (numpy, no
viewer), :mod:`.rerun_view` logs it to rerun (optional dependency rerun-sdk, the
``viz`` extra: ``pip install -e .[viz]``; imported only when used). See docs/viewing.md.
"""

from flexarm_ros.viz.bag_view import BagView, thin

__all__ = ["BagView", "bag_to_rerun", "thin"]


def bag_to_rerun(*args, **kwargs):
    """:func:`flexarm_ros.viz.rerun_view.bag_to_rerun` (imports rerun on first use)."""
    from flexarm_ros.viz.rerun_view import bag_to_rerun as convert
    return convert(*args, **kwargs)
