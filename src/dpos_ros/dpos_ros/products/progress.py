"""What the session products' makers report as they go (:func:`dpos_ros.products.solve.solve`,
:func:`dpos_ros.products.write.write`): one object of callbacks, each a no-op unless given
(dpos-process builds it from its bars, :mod:`dpos_ros.cli.progress`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


def _ignore(*_args: object) -> None:
    """A progress callback that reports nothing."""


@dataclass(frozen=True)
class ProductProgress:
    """The products' progress callbacks.

    ``sub_imu(name, outcome)``: as each sub-IMU's alignment arrives (``outcome`` one line);
    ``fit_window(done, total)``: after each window of the wing fit; ``antenna(name)``: as each
    antenna's files are written; ``bag(done, total)``: after each batch of the antenna bag."""

    sub_imu: Callable[[str, str], None] = _ignore
    fit_window: Callable[[int, int], None] = _ignore
    antenna: Callable[[str], None] = _ignore
    bag: Callable[[int, int], None] = _ignore


#: no progress reported (the default of the products' makers)
NO_PROGRESS = ProductProgress()
