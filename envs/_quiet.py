"""Import MJX and Brax without the noise they print on every import.

`mujoco.mjx` prints "Failed to import warp ..." on *stdout* when the optional
Warp backend is absent (always, on CPU), and Brax warns that it is unmaintained
each time a system is loaded. Neither tells a user of this project anything, so
the import is wrapped here once; every module of ours imports MJX and Brax from
this module rather than directly.

MuJoCo's compiler also prints a deprecation notice for HalfCheetah's
`settotalmass` straight to stderr from C. A MuJoCo warning handler (installed
only if the user has none) drops that notice and turns any other MuJoCo
warning into a Python `MujocoWarning`, which users can filter like any other.
"""

import contextlib
import io
import warnings

# Registered before the imports so warnings raised while importing are covered too.
warnings.filterwarnings("ignore", message=r"Brax System, piplines and environments")
warnings.filterwarnings("ignore", message=r".*compiler attribute 'settotalmass'")
warnings.filterwarnings("ignore", category=DeprecationWarning, module=r"brax(\..*)?")

_captured = io.StringIO()
with contextlib.redirect_stdout(_captured):
    import mujoco  # noqa: E402
    from mujoco import mjx  # noqa: E402
    import brax.envs as brax_envs  # noqa: E402

# Anything printed during the import that is not the known Warp notice is real.
for _line in _captured.getvalue().splitlines():
    if _line.strip() and "import warp" not in _line and "import mujoco_warp" not in _line:
        print(_line)



class MujocoWarning(UserWarning):
    """A warning raised by MuJoCo's C library."""


def _mujoco_warning(message: str) -> None:
    if "settotalmass" not in message:
        warnings.warn(message.strip(), MujocoWarning, stacklevel=2)


if mujoco.get_mju_user_warning() is None:
    mujoco.set_mju_user_warning(_mujoco_warning)

__all__ = ["mujoco", "mjx", "brax_envs", "MujocoWarning"]
