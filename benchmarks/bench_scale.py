"""Identification at scale: time and peak memory of naocal's chunked solve against the straightforward dense one.

Datasets: the paper's plan (144 images, 3456 vertices, 21 parameters, 0.1 px noise) repeated with fresh noise to
3456, ~100k, ~301k and ~1M vertices (each copy its own stances). Each measurement runs in its own subprocess:
wall and CPU time (medians; CPU time, time.process_time, is what to compare on a shared machine) without tracing,
then peak memory of the identify call alone (tracemalloc, which sees numpy's buffers) and the process's maximum
resident set (ru_maxrss, including the data and the interpreter).
Straightforward: the whole (2N x P) Jacobian per evaluation, LM on J^T J, covariance from J (what
solver/identify.py did before it accumulated the normal equations in chunks).
`--gls`: the GLS refinement instead (solver.gls.identify_gls from the ordinary fit's values, intrinsics free, the
NAO's 12-bit encoder steps, 0.1 px), against the dense GLS: the whole Jacobian and group matrix per evaluation and
a mask per cluster in the jackknife (what solver/gls.py did before it worked in chunks).

    python benchmarks/bench_scale.py [--sizes 3456,100000,301000,1000000] [--dense-max 301000] [--repeats 5] [--gls]

BLAS threads: one (as `naocal` runs).
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def make_data(n_vertices: int, seed: int = 0):
    """The paper-size synthetic plan, repeated until it has at least `n_vertices` vertices; fresh 0.1 px noise."""
    import numpy as np

    from naocal.solver.model import ModelData
    from naocal.sim.synthetic import random_truth, synthesize

    rng = np.random.default_rng(seed)
    truth = random_truth(rng)
    base = synthesize(rng, truth, pixel_noise_px=0.0)
    copies = max(1, -(-n_vertices // base.n_rows))
    M, N = base.n_images, base.n_rows
    tile = lambda a: np.concatenate([a] * copies)  # noqa: E731
    data = ModelData(
        image_of_row=np.concatenate([base.image_of_row + k * M for k in range(copies)]), vertex=tile(base.vertex),
        uv_px=tile(base.uv_px) + rng.normal(0.0, 0.1, size=(copies * N, 2)), p_mount=tile(base.p_mount),
        target=tile(base.target), image_id=np.arange(copies * M),
        stance=np.concatenate([base.stance + 1000 * k for k in range(copies)]), head_posture=tile(base.head_posture),
        theta=tile(base.theta), direction=tile(base.direction), velocity=None, cameras=base.cameras,
        camera=tile(base.camera), joints=base.joints, robot=base.robot, tau=tile(base.tau))
    return data, truth


def dense_identify(data, registry, max_iterations=100):
    """The straightforward solve: the whole Jacobian at every evaluation, LM on J^T J, clustered covariance."""
    import numpy as np

    from naocal.solver.identify import UNIDENTIFIABLE_RATIO
    from naocal.solver.model import Model
    from naocal.solver.scoretest import stance_cluster_of_image

    model = Model(data, registry)
    scales = registry.scales
    x = registry.zeros()

    def evaluate(x):
        r, J = model.evaluate(x)
        return r.reshape(-1), J.reshape(r.size, -1) * scales

    r, Js = evaluate(x)
    A, g, cost = Js.T @ Js, Js.T @ r, 0.5 * float(r @ r)
    mu = 1e-6 * float(np.max(np.diag(A)))
    for _ in range(max_iterations):
        step = -np.linalg.solve(A + mu * np.eye(len(x)), g)
        predicted = 0.5 * float(step @ (mu * step - g))
        if predicted <= 1e-10 * cost:
            break
        r_new, Js_new = evaluate(x + step * scales)
        cost_new = 0.5 * float(r_new @ r_new)
        rho = (cost - cost_new) / predicted
        if rho > 0:
            x, r, Js, cost = x + step * scales, r_new, Js_new, cost_new
            A, g = Js.T @ Js, Js.T @ r
            mu *= max(1 / 3, 1 - (2 * rho - 1) ** 3)
        else:
            mu *= 2
    eigenvalues, vectors = np.linalg.eigh(A)
    keep = eigenvalues > UNIDENTIFIABLE_RATIO ** 2 * eigenvalues.max()
    bread = (vectors[:, keep] / eigenvalues[keep]) @ vectors[:, keep].T
    rows = np.repeat(model.data.image_of_row, 2)
    cluster = stance_cluster_of_image(model.data)[rows]
    scores = np.zeros((cluster.max() + 1, len(x)))
    np.add.at(scores, cluster, Js * r[:, None])
    covariance = bread @ (scores.T @ scores) @ bread * np.outer(scales, scales)
    return x, np.sqrt(np.diag(covariance))


def dense_gls(data, registry, x0, step_rad, sigma_px, max_iterations=50):
    """The straightforward GLS (what solver/gls.py did before it worked in chunks): the whole Jacobian and the whole
    (2N x k) group matrix at every evaluation, Sigma^-1 J by Woodbury, the jackknife with a mask per cluster."""
    import numpy as np
    from scipy.sparse import csc_matrix, diags
    from scipy.sparse.linalg import splu

    from naocal.solver.effects import EFFECTS
    from naocal.solver.gls import angle_error_groups
    from naocal.solver.identify import Normal, levenberg_marquardt
    from naocal.solver.model import Model
    from naocal.solver.registry import Registry
    from naocal.solver.scoretest import stance_cluster_of_image

    model = Model(data, registry)
    data, scales, s2 = model.data, registry.scales[registry.free_index], sigma_px ** 2
    offsets = tuple(name for name, e in EFFECTS.items() if e.reading_offsets)
    full = Registry(tuple(dict.fromkeys(registry.effects + offsets)), setup=registry.setup)
    J_full = Model(data, full).evaluate(full.from_dict(registry.as_dict(x0)))[1]
    column = {data.column(p.joint): full.index[p.name] for p in full.parameters if EFFECTS[p.effect].reading_offsets}
    rows, cols, vals, q2, k = [], [], [], [], 0
    coordinate = np.arange(2 * data.n_rows).reshape(-1, 2)
    for c, group in angle_error_groups(data, step_rad):
        a = J_full[:, :, column[c]]
        used = np.any(a != 0, axis=1)
        ids, g_row = np.unique(group[data.image_of_row][used], return_inverse=True)
        rows.append(coordinate[used].reshape(-1))
        cols.append(np.repeat(k + g_row, 2))
        vals.append(a[used].reshape(-1))
        q2.append(np.full(len(ids), step_rad[c] ** 2 / 12.0))
        k += len(ids)
    del J_full
    A = csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(2 * data.n_rows, k))
    inner = splu(csc_matrix(diags(s2 / np.concatenate(q2)) + A.T @ A))
    whiten = lambda M: (M - A @ inner.solve(np.asarray(A.T @ M))) / s2  # noqa: E731

    def dense(free):
        r, J = model.evaluate(registry.unpack(free, x0))
        return r.reshape(-1), J.reshape(r.size, -1) * scales

    def normal_at(free):
        r, Js = dense(free)
        u, SJ = whiten(r), whiten(Js)
        return Normal(Js.T @ SJ, Js.T @ u, 0.5 * float(r @ u), r.reshape(-1, 2), None)

    free = levenberg_marquardt(normal_at, registry.pack(x0), scales, max_iterations=max_iterations)[0]
    r, Js = dense(free)
    u, SJ = whiten(r), whiten(Js)
    cluster = stance_cluster_of_image(data)  # joined where a group spans two stances (union-find)
    parent = list(range(int(cluster.max()) + 1))

    def root(i):
        while parent[i] != i:
            i = parent[i]
        return i

    image_of_coordinate = np.repeat(data.image_of_row, 2)
    for g in range(k):
        members = np.unique(cluster[image_of_coordinate[A.indices[A.indptr[g]:A.indptr[g + 1]]]])
        for m in members[1:]:
            parent[root(int(m))] = root(int(members[0]))
    cluster = np.unique([root(int(c)) for c in cluster], return_inverse=True)[1].reshape(-1)
    of_coordinate = cluster[image_of_coordinate]
    C = int(cluster.max()) + 1
    A_c = np.array([Js[of_coordinate == c].T @ SJ[of_coordinate == c] for c in range(C)])
    g_c = np.array([Js[of_coordinate == c].T @ u[of_coordinate == c] for c in range(C)])
    deltas = np.array([np.linalg.lstsq(A_c.sum(axis=0) - A_c[c], g_c[c], rcond=None)[0] for c in range(C)])
    centred = deltas - deltas.mean(axis=0)
    covariance = (C - 1) / C * centred.T @ centred * np.outer(scales, scales)
    return registry.unpack(free, x0), np.sqrt(np.diag(covariance))


def measure(n_vertices: int, method: str, repeats: int) -> dict:
    """In this process: time (median of `repeats`) and then peak traced memory of one more solve."""
    import time
    import tracemalloc
    import resource

    import numpy as np

    from naocal.solver.identify import identify
    from naocal.solver.registry import Registry

    data, truth = make_data(n_vertices)
    if method.startswith("gls"):  # as `naocal identify` refines: intrinsics free, from the ordinary fit's values
        from naocal.solver.gls import identify_gls

        registry = Registry(("intrinsics",))
        ordinary = identify(data, registry)
        step_rad = np.full(len(data.joints), 2 * np.pi / 4096)  # the NAO's 12-bit encoders
        gls = identify_gls if method == "gls" else dense_gls
        solve = lambda: gls(ordinary.model.data, registry, ordinary.values, step_rad, 0.1)  # noqa: E731
    else:
        registry = Registry()
        solve = (lambda: identify(data, registry)) if method == "chunked" else (lambda: dense_identify(data, registry))
    times, cpu_times = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        out = solve()
        times.append(time.perf_counter() - start)
        cpu_times.append(time.process_time() - start_cpu)
    values = out.values if method in ("chunked", "gls") else out[0]
    tracemalloc.start()
    solve()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    error = max(abs(values[registry.index[n]] - truth[n]) for n in registry.names if n.startswith("joint_offset"))
    return {"n_vertices": int(data.n_rows), "method": method, "time_s": statistics.median(times),
            "cpu_s": statistics.median(cpu_times),
            "peak_bytes": int(peak), "maxrss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
            "worst_joint_error_deg": float(np.degrees(error))}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="3456,100000,301000,1000000")
    parser.add_argument("--dense-max", type=int, default=301000,
                        help="largest size the dense solve is run at (its memory: ~1.1 KB per vertex)")
    parser.add_argument("--repeats", type=int, default=3, help="timed solves per size (3456: 10x as many)")
    parser.add_argument("--gls", action="store_true",
                        help="measure the GLS refinement (solver/gls.py, chunked) against the dense GLS instead")
    parser.add_argument("--child", nargs=3, metavar=("N", "METHOD", "REPEATS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(measure(int(args.child[0]), args.child[1], int(args.child[2]))))
        return
    print(f"BLAS threads: OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}; each line its own process")
    print(f"{'vertices':>9s} {'method':9s} {'wall':>10s} {'CPU':>10s} {'peak (identify)':>16s} {'per vertex':>11s} "
          f"{'maxrss':>9s} {'worst joint':>12s}")
    dense_per_vertex = None  # measured at the largest size the dense solve ran
    for size in (int(s) for s in args.sizes.split(",")):
        repeats = args.repeats * 10 if size < 10000 else args.repeats
        rows = {}
        for method in ("gls", "gls-dense") if args.gls else ("chunked", "dense"):
            if method.endswith("dense") and size > args.dense_max:
                guess = "" if dense_per_vertex is None else \
                    f": it would need about {dense_per_vertex * size / 2 ** 20:.0f} MiB at its measured bytes per vertex"
                print(f"{size:9d} {method:9s} skipped above --dense-max{guess}")
                continue
            out = subprocess.run([sys.executable, __file__, "--child", str(size), method, str(repeats)],
                                 capture_output=True, text=True, check=True)
            row = rows[method] = json.loads(out.stdout)
            if method.endswith("dense"):
                dense_per_vertex = row["peak_bytes"] / row["n_vertices"]
            print(f"{row['n_vertices']:9d} {method:9s} {row['time_s'] * 1e3:8.1f} ms {row['cpu_s'] * 1e3:8.1f} ms "
                  f"{row['peak_bytes'] / 2 ** 20:12.1f} MiB {row['peak_bytes'] / row['n_vertices']:8.0f} B "
                  f"{row['maxrss_bytes'] / 2 ** 20:7.0f} MiB {row['worst_joint_error_deg']:9.4f} deg", flush=True)
        if len(rows) == 2:
            c, d = rows.values()
            print(f"{'':9s} ratio    dense/chunked: wall {d['time_s'] / c['time_s']:.2f}x, "
                  f"CPU {d['cpu_s'] / c['cpu_s']:.2f}x, "
                  f"peak memory {d['peak_bytes'] / c['peak_bytes']:.1f}x", flush=True)


if __name__ == "__main__":
    main()
