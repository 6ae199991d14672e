"""The twin's built-in pd law as a pythonfmu slave: an FMU that needs Python (docs/fmi.md), built with

    python -m pythonfmu build -f examples/fmu-pd/pypd.py -d OUT_DIR

It runs on the twin's Python loop; the order of operations is that of src/gantry_twin/controllers/pd.py.
"""

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class pypd(Fmi2Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        names = ["x_m", "y_m", "dx_m_s", "dy_m_s", "x_d_m", "y_d_m", "dx_d_m_s", "dy_d_m_s", "ddx_d_m_s2", "ddy_d_m_s2"]
        for name in names:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input))
        for name in ["u_x_v", "u_y_v"]:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.output))
        gains = {
            "kp_x": 1e4,
            "kp_y": 1e4,
            "kd_x": 100.0,
            "kd_y": 100.0,
            "kv_x": 0.5,
            "kv_y": 0.7,
            "ka_x": 0.12,
            "ka_y": 0.5,
        }
        for name, start in gains.items():  # pd's defaults, as in pd.c
            setattr(self, name, start)
            self.register_variable(Real(name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))

    def do_step(self, current_time, step_size):
        for a in "xy":
            e = getattr(self, f"{a}_m") - getattr(self, f"{a}_d_m")
            de = getattr(self, f"d{a}_m_s") - getattr(self, f"d{a}_d_m_s")
            u = -getattr(self, f"kp_{a}") * e - getattr(self, f"kd_{a}") * de
            u = (
                u
                + getattr(self, f"kv_{a}") * getattr(self, f"d{a}_d_m_s")
                + getattr(self, f"ka_{a}") * getattr(self, f"dd{a}_d_m_s2")
            )
            setattr(self, f"u_{a}_v", u)
        return True
