"""The rendered demo board both spot-over-the-rim test modules measure on (not a test module)."""

from helicalib.sim.render import (
    DEMO_CAMERA_ENU_M,
    Lighting,
    demo_target,
    look_at_pose,
    render_frame,
)
from helicalib.vision.marks import find_marks

EXPOSED = Lighting(ambient=25.0, background=10.0)
"""As the simulated plant's cameras expose: the white board at 25 grey levels."""


def demo_scene():
    """(target, camera pose, marks found) of the demo board seen by the demo camera."""
    target = demo_target()
    pose = look_at_pose(DEMO_CAMERA_ENU_M, target, 5200, (1280, 1024))
    marks = find_marks(render_frame(target, pose, (), EXPOSED, rng=3), target)
    assert marks.found
    return target, pose, marks
