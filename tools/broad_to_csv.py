#!/usr/bin/env python3
"""Converts BROAD trials to one plain CSV per trial plus a manifest.

BROAD (Berlin Robust Orientation estimation Assessment Dataset; Laidig,
Caruso, Cereatti, Seel, Data 6(7), 2021, https://github.com/dlaidig/broad)
is licensed CC BY 4.0. Each trial holds a MEMS IMU (myon aktos-t) sampled at
`sampling_rate` (2000/7 = 285.714 Hz) with optical motion-capture truth:

  imu_acc  (N, 3)  specific force, m/s², sensor frame (z up: +9.8 on z flat)
  imu_gyr  (N, 3)  angular rate, rad/s, sensor frame
  imu_mag  (N, 3)  magnetic field, µT, sensor frame
  opt_quat (N, 4)  w, x, y, z: sensor-to-ENU orientation (NaN where the
                   cameras lost the markers); its ENU frame is aligned to
                   magnetic north by the dataset's authors
  movement (N,)    true for the samples BROAD scores (the movement phase)

Output (nothing is rotated or rescaled here; the Rust loader
src/eval/recording/frames.rs maps the frames):

  OUT/<trial>.csv      header, then t_s,ax,ay,az,gx,gy,gz,mx,my,mz,qw,qx,qy,qz
                       with t_s = index / sampling_rate and "nan" truth
                       where the optical system had none
  OUT/manifest.json    {"dataset", "licence", "trials": [{name, file,
                       rate_hz, samples, description, groups, source,
                       movement: [[first, end), ...] sample ranges}]}

Usage:
  python tools/broad_to_csv.py --broad BARE_GIT_DIR --out /work/data/broad \
      [--armanasq BARE_GIT_DIR]

--broad is a checkout or bare git directory of dlaidig/broad (the .mat or
.hdf5 file of each trial is read, whichever is present). Trials absent
there can be taken from Armanasq/BROAD_IMU_dataset (--armanasq), which
stores the same samples as input<i>.mat / output<i>.mat but with every
row of missing truth deleted and without time, rate or movement mask;
those go to OUT/partial/ with time reconstructed at the nominal rate
(so each deleted run, 20-100 ms, is a silent time jump) and the whole
trial marked as movement. Requires h5py, numpy, scipy.
"""

import argparse
import io
import json
import subprocess
from pathlib import Path

import h5py
import numpy as np
import scipy.io as sio

NOMINAL_RATE_HZ = 2000.0 / 7.0
HEADER = "t_s,ax,ay,az,gx,gy,gz,mx,my,mz,qw,qx,qy,qz"
# Armanasq/BROAD_IMU_dataset CreateDatset.m numbers its files in this order.
ARMANASQ_ORDER = list(range(26, 40)) + list(range(1, 26))


def git_blob(repo: Path, path: str) -> bytes | None:
    """A file of a checkout or bare git directory; None if absent or a pointer."""
    plain = repo / path
    if plain.is_file():
        data = plain.read_bytes()
    else:
        run = subprocess.run(["git", "--git-dir", str(repo), "show", f"HEAD:{path}"],
                             capture_output=True)
        if run.returncode != 0:
            return None
        data = run.stdout
    if data.startswith(b"version https://git-lfs") or len(data) < 1024:
        return None
    return data


def load_broad(repo: Path, name: str) -> dict | None:
    data = git_blob(repo, f"data_mat/{name}.mat")
    if data is not None:
        m = sio.loadmat(io.BytesIO(data))
        return dict(acc=m["imu_acc"], gyr=m["imu_gyr"], mag=m["imu_mag"], quat=m["opt_quat"],
                    rate=float(m["sampling_rate"].item()),
                    movement=m["movement"].ravel().astype(bool))
    data = git_blob(repo, f"data_hdf5/{name}.hdf5")
    if data is not None:
        with h5py.File(io.BytesIO(data), "r") as f:
            return dict(acc=f["imu_acc"][()], gyr=f["imu_gyr"][()], mag=f["imu_mag"][()],
                        quat=f["opt_quat"][()], rate=float(f.attrs["sampling_rate"]),
                        movement=f["movement"][()].astype(bool))
    return None


def load_armanasq(repo: Path, name: str) -> dict | None:
    index = ARMANASQ_ORDER.index(int(name[:2])) + 1
    inputs = git_blob(repo, f"Dataset/input{index}.mat")
    outputs = git_blob(repo, f"Dataset/output{index}.mat")
    if inputs is None or outputs is None:
        return None
    x = sio.loadmat(io.BytesIO(inputs))["in_temp"]
    q = sio.loadmat(io.BytesIO(outputs))["out_temp"]
    return dict(acc=x[:, 0:3], gyr=x[:, 3:6], mag=x[:, 6:9], quat=q, rate=NOMINAL_RATE_HZ,
                movement=np.ones(len(x), bool))


def ranges(mask: np.ndarray) -> list[list[int]]:
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return [[int(a), int(b)] for a, b in zip(np.where(edges == 1)[0], np.where(edges == -1)[0])]


def write_csv(path: Path, trial: dict) -> None:
    n = len(trial["acc"])
    t = np.arange(n) / trial["rate"]
    with open(path, "w") as f:
        f.write(HEADER + "\n")
        for i in range(n):
            sensors = np.r_[trial["acc"][i], trial["gyr"][i], trial["mag"][i]]
            f.write(f"{t[i]:.6f}," + ",".join(f"{v:.8g}" for v in sensors) + ","
                    + ",".join(f"{v:.9f}" for v in trial["quat"][i]) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--broad", type=Path, required=True)
    parser.add_argument("--armanasq", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()

    info = json.loads(git_blob(args.broad, "data_mat/trials.json").decode())
    manifests = {"": [], "partial": []}
    for name, meta in info["trials"].items():
        trial, source, where = load_broad(args.broad, name), "dlaidig/broad", ""
        if trial is None and args.armanasq is not None:
            trial = load_armanasq(args.armanasq, name)
            source = ("Armanasq/BROAD_IMU_dataset: rows without truth deleted, time "
                      "reconstructed at the nominal rate, no movement mask")
            where = "partial"
        if trial is None:
            print(f"{name}: not available")
            continue
        out = args.out / where
        out.mkdir(parents=True, exist_ok=True)
        write_csv(out / f"{name}.csv", trial)
        manifests[where].append(dict(
            name=name, file=f"{name}.csv", rate_hz=trial["rate"], samples=len(trial["acc"]),
            description=meta["description"], groups=meta["groups"], source=source,
            movement=ranges(trial["movement"])))
        print(f"{name}: {len(trial['acc'])} samples from {source[:24]}")
    for where, trials in manifests.items():
        if trials:
            manifest = dict(
                dataset="BROAD, Berlin Robust Orientation estimation Assessment Dataset "
                        "(Laidig et al., Data 6(7), 2021; https://github.com/dlaidig/broad)",
                licence="CC BY 4.0",
                columns=HEADER,
                frames="sensor frame z up (acc +9.8 on z when flat); quaternion w,x,y,z "
                       "sensor-to-ENU, ENU aligned to magnetic north; gyro rad/s, "
                       "acc m/s², mag µT",
                trials=trials)
            (args.out / where / "manifest.json").write_text(json.dumps(manifest, indent=1))


if __name__ == "__main__":
    main()
