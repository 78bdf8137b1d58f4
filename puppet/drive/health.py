"""The host's current and temperature stops for driven servos, per model from the model table.

Every cycle's state read (``DriveBus.read_state``) is checked against two host limits, below
the servo's own protections so the host stops first, with a clear message:

- temperature: Present Temperature above the servo's Temperature Limit (read at setup) minus
  ``temperature_margin_c``, at most ``temperature_cap_c``: stops at once;
- current: on a current-sensing model (``ServoModel.current_unit_ma``), Present Current above
  ``current_fraction`` of the servo's Current Limit (read at setup, in mA through the model's
  unit) for longer than ``current_sustain_s``. A model that senses no current (XL430, 2XL430,
  XC430: Present Load, ``PRESENT_LOAD_UNIT_PCT``) gets the same rule on its load: Present Load
  above ``current_fraction`` of 100 % for longer than ``current_sustain_s``.

``perform`` checks every cycle; ``live`` its actuators every ``actuators.HEALTH_CHECK_CYCLES``.
"""

from __future__ import annotations

import numpy as np

from puppet.drive.errors import HealthStop
from puppet.servo_models import PRESENT_LOAD_UNIT_PCT

TEMPERATURE_MARGIN_C = 10.0
"""Host temperature limit = the servo's Temperature Limit minus this."""
TEMPERATURE_CAP_C = 65.0
"""... and never above this."""
CURRENT_FRACTION = 0.8
"""Host cap on sustained current (or load): this fraction of the Current Limit (or of 100 %)."""
CURRENT_SUSTAIN_S = 0.3
"""Seconds above the cap before the stop (a short peak, e.g. an acceleration, is allowed)."""


class CurrentTemperatureStop:
    """The two host limits over (k,) servos in bus order.

    ids: (k,) servo ids. setups: (k,) ``servos.ServoSetup`` (temperature_limit, current_limit_ma,
    current_unit_ma). ``temp_limit`` (k,) deg C; ``cap`` (k,) mA, or % of load where ``load``;
    ``scale`` (k,) mA (or %) per raw unit of item 126.
    """

    def __init__(self, ids, setups, *, temperature_margin_c: float = TEMPERATURE_MARGIN_C,
                 temperature_cap_c: float = TEMPERATURE_CAP_C,
                 current_fraction: float = CURRENT_FRACTION,
                 current_sustain_s: float = CURRENT_SUSTAIN_S) -> None:
        self.ids = [int(i) for i in ids]
        self.setups = list(setups)
        self.sustain_s = current_sustain_s
        self.temp_limit = np.array([min(s.temperature_limit - temperature_margin_c,
                                        temperature_cap_c) for s in self.setups], float)
        self.load = np.array([s.current_unit_ma is None for s in self.setups], bool)
        self.scale = np.array([PRESENT_LOAD_UNIT_PCT if s.current_unit_ma is None
                               else s.current_unit_ma for s in self.setups], float)
        self.cap = np.array([100.0 * current_fraction if s.current_unit_ma is None
                             else s.current_limit_ma * current_fraction for s in self.setups],
                            float)
        k = len(self.ids)
        self.over_s = np.zeros(k)
        self._value = np.zeros(k)

    def check(self, state, dt: float) -> None:
        """Raise HealthStop naming the servo when ``state`` (ok, temperature, current: (k,))
        breaks a limit; ``dt``: seconds since the last check."""
        hot = state.ok & (state.temperature > self.temp_limit)
        if hot.any():
            n = int(np.flatnonzero(hot)[0])
            raise HealthStop(self.ids[n], f"Present Temperature {state.temperature[n]} C above "
                             f"the host limit {self.temp_limit[n]:.0f} C (servo limit "
                             f"{self.setups[n].temperature_limit} C)")
        value = self._value
        np.abs(state.current, out=value, casting="unsafe")
        value *= self.scale
        over = state.ok & (value > self.cap)
        self.over_s = np.where(over, self.over_s + dt, 0.0)
        if (self.over_s > self.sustain_s).any():
            n = int(np.argmax(self.over_s))
            if self.load[n]:
                what = (f"Present Load {value[n]:.1f} % above the host cap {self.cap[n]:.0f} %")
            else:
                what = f"Present Current {value[n]:.0f} mA above the host cap {self.cap[n]:.0f} mA"
            raise HealthStop(self.ids[n], f"{what} for {self.over_s[n]:.2f} s")
