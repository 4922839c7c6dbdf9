"""Where the robots' description files are, and Pinocchio loaded with a clear refusal.

``example-robot-data`` (the extra ``robots``) ships its URDFs as plain files under the
``cmeel.prefix/share/example-robot-data/robots`` folder of its wheel, with no Python
module to import. The folder is found from the distribution's own file list
(``importlib.metadata``), so it does not depend on where site-packages is; a missing
package, or a file not in it, is refused with what to install or what exists.
"""

from __future__ import annotations

import importlib.metadata
import os
import pathlib

__all__ = ["example_robot_data", "require_pinocchio", "robot_file"]

#: the extra that installs Pinocchio and example-robot-data
INSTALL = "pip install 'bderiv[robots]'  (Pinocchio: pin, and example-robot-data)"


def require_pinocchio():
    """The ``pinocchio`` module, or an ImportError that says how to install it."""
    try:
        import pinocchio
    except ImportError as err:
        raise ImportError(f"bderiv.robots needs Pinocchio: {INSTALL}") from err
    return pinocchio


def example_robot_data() -> pathlib.Path:
    """The ``robots`` folder of the installed example-robot-data package.

    Raises
    ------
    ImportError
        When the distribution is not installed or holds no ``robots`` folder.
    """
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError as err:
        raise ImportError(f"the robots' description files come from example-robot-data, "
                          f"which is not installed: {INSTALL}") from err
    marker = "share/example-robot-data/robots/"
    for entry in dist.files or ():
        text = str(entry).replace("\\", "/")
        if marker in text:
            root = pathlib.Path(str(dist.locate_file(text[:text.index(marker) + len(marker)])))
            if root.is_dir():
                return root
    raise ImportError(f"example-robot-data {dist.version} is installed but its folder "
                      f"{marker!r} was not found among its files: reinstall it ({INSTALL})")


def robot_file(name) -> pathlib.Path:
    """The description file ``name`` of example-robot-data, e.g.
    ``"solo_description/robots/solo12.urdf"``, or a path of your own.

    Raises
    ------
    TypeError
        When ``name`` is not a path (str or os.PathLike; bytes neither).
    FileNotFoundError
        Naming the file; for a name inside example-robot-data, the URDFs found in its
        robot's folder.
    """
    if isinstance(name, bytes) or not isinstance(name, (str, os.PathLike)):
        raise TypeError(f"source, the robot's description file, must be a path (str or "
                        f"os.PathLike) or a pinocchio.Model, got {type(name).__name__} "
                        f"{name!r:.80}")
    path = pathlib.Path(name)
    if path.is_file():
        return path
    if path.is_absolute():  # the user's own file: no search (root / path would be path)
        raise FileNotFoundError(f"no robot description file {str(name)!r}: "
                                f"{'a folder' if path.is_dir() else 'no such file'}")
    root = example_robot_data()
    found = root / path
    if found.is_file():
        return found
    folder = root / path.parts[0] if path.parts else root
    near = sorted(str(p.relative_to(root)) for p in folder.rglob("*.urdf")) if folder.is_dir() \
        else sorted(p.name for p in root.iterdir() if p.is_dir())
    raise FileNotFoundError(f"no robot description file {str(name)!r} (neither a file nor in "
                            f"{root}); there: {', '.join(near[:20]) or 'nothing'}")
