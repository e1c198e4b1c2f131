"""The table of docs/joint.md: wfjax's peak contact force for a smooth wheel over a dipped rail
joint against Jenkins et al.'s P2 estimate.

    python benchmarks/joint_p2.py            # ~1 min on a laptop CPU

A v-shaped and a cosine dip, 1 mm deep and 0.4 m long (v: total angle 2 alpha = 4 d / l =
0.01 rad), centred mid-bay (x = L_S / 2, a suspended joint), smooth wheel (``Flat.none()``),
Hertz contact with the profile input. For each speed: the peak contact force of the run, the
peak of the contact force low-passed at 150 Hz (zero phase, 4th-order Butterworth: the P2
resonance at ~70 Hz passes, the P1 transient at ~1 kHz does not) and Jenkins' P2 with the
track's equivalent mass, stiffness and damping read from the model's receptance at the joint
(:func:`wfjax.scenario.joint.equivalent_track`). For the v dip also the wheel's downward velocity as
it reaches the joint, over the ``alpha v`` of a wheel running down the ramp in steady descent
(Jenkins' assumption), and a second table: the same angle over shorter dips.
"""

from __future__ import annotations

import numpy as np
import scipy.signal
from _tracks import RECORDED  # benchmarks/, the script's folder

import wfjax as wf
from wfjax.scenario.joint import Joint, equivalent_track

SPEEDS_KMH = (50, 100, 150, 200)
DEPTH, LENGTH, POSITION = 1e-3, 0.4, 0.325
CUTOFF = 150.0  # Hz
CONFIG = wf.SimConfig(run_in=1.0, run_out=1.0)  # the dip well inside the run, both sides


def lowpass(force, dt):
    b, a = scipy.signal.butter(4, CUTOFF, fs=1.0 / dt)
    return scipy.signal.filtfilt(b, a, force)


def run(joint, kmh):
    """(peak, low-passed peak, min [N], wheel's downward velocity at the joint / alpha v)."""
    v = kmh / 3.6
    res = wf.simulate(wf.Flat.none(), v, contact="hertz-profile", config=CONFIG,
                      roughness=joint.add_to(None))
    force, t, x = np.asarray(res.force), np.asarray(res.t), np.asarray(res.x)
    velocity = np.gradient(np.asarray(res.wheel_disp), t)  # downwards
    arrival = velocity[np.argmin(np.abs(x - joint.position))] / (joint.max_slope * v)
    return force.max(), lowpass(force, t[1] - t[0]).max(), force.min(), arrival


def main():
    wheel = wf.Wheel()
    eq = equivalent_track(wf.Track(**RECORDED), float(wheel.wheelset_mass + wheel.small_mass),
                          POSITION)
    print(f"equivalent track at x = {POSITION} m: M_t = {eq.mass:.1f} kg, K_t = "
          f"{eq.stiffness / 1e6:.1f} MN/m, C_t = {eq.damping / 1e3:.1f} kN s/m, P2 resonance "
          f"{eq.frequency:.1f} Hz")
    print("| shape | speed km/h | peak kN | low-passed peak kN | min kN | Jenkins P2 kN | "
          "descent at the joint / alpha v |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for shape in ("v", "cosine"):
        joint = Joint(POSITION, DEPTH, LENGTH, shape)
        for kmh in SPEEDS_KMH:
            peak, smooth, low, arrival = run(joint, kmh)
            ratio = f"{arrival:.2f}" if shape == "v" else "-"
            print(f"| {shape} | {kmh} | {peak / 1e3:.1f} | {smooth / 1e3:.1f} | "
                  f"{low / 1e3:.1f} | {joint.p2(kmh / 3.6) / 1e3:.1f} | {ratio} |")
    print()
    print("| v dip (2 alpha = 0.01 rad) | speed km/h | peak kN | low-passed peak kN | "
          "Jenkins P2 kN | descent at the joint / alpha v |")
    print("| --- | --- | --- | --- | --- | --- |")
    for depth, length in ((1e-3, 0.4), (0.5e-3, 0.2), (0.25e-3, 0.1)):
        joint = Joint(POSITION, depth, length, "v")
        for kmh in (100, 150):
            peak, smooth, _, arrival = run(joint, kmh)
            print(f"| {depth * 1e3:g} mm over {length:g} m | {kmh} | {peak / 1e3:.1f} | "
                  f"{smooth / 1e3:.1f} | {joint.p2(kmh / 3.6) / 1e3:.1f} | {arrival:.2f} |")

if __name__ == "__main__":
    main()
