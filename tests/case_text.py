"""The text of a small valid case file, for tests that write case files (and mutate them): the
Dzhanibekov body I = diag(1, 2, 3), w0 = (wx, 5, 0) rad/s, no gravity, no loads."""
from __future__ import annotations

INERTIA = "inertia = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]"
MASS_AND_INERTIA = "mass = 1.0\n" + INERTIA


def case_text(name: str = "good", description: str = "A valid case that the bad ones are mutations of.",
              horizon: str = "duration = 0.05", dt: str = "[0.01]", body: str = MASS_AND_INERTIA,
              wx: float | str = 0.01) -> str:
    """A case file's TOML: ``horizon`` is its ``duration = ...`` or ``duration_steps = ...`` line,
    ``dt`` the TOML value of ``dt``, ``body`` the lines of its [body] table."""
    return f"""name = "{name}"
description = "{description}"
{horizon}
dt = {dt}
[body]
{body}
[initial]
position = [0.0, 0.0, 0.0]
orientation = [1.0, 0.0, 0.0, 0.0]
linear_velocity = [0.0, 0.0, 0.0]
angular_velocity = [{wx}, 5.0, 0.0]
[world]
gravity = [0.0, 0.0, 0.0]
"""


GOOD = case_text()
