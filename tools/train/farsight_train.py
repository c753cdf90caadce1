"""farsight's trainer: LRN's affordance heatmap and FITAM's far-field
ensembles on a small CPU image encoder, from `farsight dataset` folders,
and HIP's learned trajectory density from `farsight-sim hip-dataset`
folders, exported to ONNX with the model config the inference stage (or,
for HIP, the subgoal stage) reads.

    python farsight_train.py lrn      --train DIR --val DIR --out models/sim-lrn
    python farsight_train.py fitam    --train DIR --val DIR --out models/sim-fitam
    python farsight_train.py evaluate --data DIR --lrn models/sim-lrn --fitam models/sim-fitam --out report/
    python farsight_train.py hip      --train DIR --val DIR --library hip-library.toml --out models/sim-hip
    python farsight_train.py hip-report --model models/sim-hip --library hip-library.toml --prior DIR --data DIR...

The encoder: four 3x3 convolutions (3-16-32-32-32 channels, the first two
with stride 2) on a 160x96 RGB frame, so 24x40 feature cells. LRN's head is
a 1x1 convolution to one logit per cell (sigmoid in the config). FITAM, as
its reference code: the encoder is first trained with one linear head on
all labels, then frozen; each image slice's features (the slice's columns
averaged, 32 channels x 24 rows) feed 15 linear members per radial bin, each
trained on its own seeded 80/20 split with early stopping (patience 10),
cross-entropy weighted by swath coverage and inverse class frequency.
Evaluation follows LRN Table II (targets binarised at 0.15; AUROC; F1,
precision, recall, FPR and FNR at the best-F1 threshold) and FITAM Table IV
(class-weighted one-vs-rest ROC AUC per radial bin), from the exported ONNX
files run by ONNX Runtime.
"""

import argparse
import csv
import json
import os
import sys
import time

import numpy as np

# One thread per core is all this CPU work wants; set before JAX starts.
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=true")
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

CHANNELS = [16, 32, 32, 32]
STRIDES = [2, 2, 1, 1]
OPSET = 17


def progress(label, i, n, extra=""):
    width = 30
    done = int(width * i / max(n, 1))
    sys.stderr.write(f"\r{label} [{'#' * done}{'.' * (width - done)}] {i}/{n} {extra}   ")
    if i >= n:
        sys.stderr.write("\n")
    sys.stderr.flush()


# ---------------------------------------------------------------- data


def read_manifest(folder):
    import tomllib

    with open(os.path.join(folder, "dataset.toml"), "rb") as f:
        return tomllib.load(f)


def load_dataset(folder, want_lrn=True, want_fitam=True):
    from PIL import Image

    m = read_manifest(folder)
    o = m["options"]
    rows = list(csv.DictReader(open(os.path.join(folder, "frames.csv"))))
    n = len(rows)
    h, w = o["image_height"], o["image_width"]
    images = np.zeros((n, 3, h, w), np.float32)
    lrn_value = np.zeros((n, h, w), np.float32)
    lrn_mask = np.zeros((n, h, w), np.float32)
    ids = [int(r["frame"]) for r in rows]
    index = {f: i for i, f in enumerate(ids)}
    for i, r in enumerate(rows):
        img = np.asarray(Image.open(os.path.join(folder, "images", f"{ids[i]:06d}.png")).convert("RGB"))
        images[i] = img.transpose(2, 0, 1) / 255.0
        if want_lrn and r["lrn"] == "1":
            la = np.asarray(Image.open(os.path.join(folder, "lrn", f"{ids[i]:06d}.png")).convert("LA"))
            lrn_value[i] = la[..., 0] / 255.0
            lrn_mask[i] = la[..., 1] > 0
        if i % 100 == 0 or i == n - 1:
            progress(f"loading {os.path.basename(folder.rstrip('/'))}", i + 1, n)
    radial = len(o["fitam"]["range_edges_m"]) - 1
    classes = len(o["fitam"]["class_speeds_mps"])
    slices = o["slices"]
    fit_y = -np.ones((n, slices, radial), np.int32)
    fit_w = np.zeros((n, slices, radial), np.float32)
    if want_fitam:
        for r in csv.DictReader(open(os.path.join(folder, "fitam.csv"))):
            i = index[int(r["frame"])]
            s, b = int(r["slice"]), int(r["radial_bin"])
            fit_y[i, s, b] = int(r["class"])
            fit_w[i, s, b] = float(r["weight"])
    recording = np.array([int(r["recording"]) for r in rows])
    return dict(options=o, images=images, lrn_value=lrn_value, lrn_mask=lrn_mask,
                fit_y=fit_y, fit_w=fit_w, radial=radial, classes=classes, slices=slices,
                recording=recording, has_lrn=np.array([r["lrn"] == "1" for r in rows]))


def pool_labels(value, mask, k):
    """Label images -> the output grid: per k x k block, the mean affordance
    of its labelled pixels, and whether any pixel was labelled."""
    n, h, w = value.shape
    v = (value * mask).reshape(n, h // k, k, w // k, k).sum((2, 4))
    c = mask.reshape(n, h // k, k, w // k, k).sum((2, 4))
    return np.where(c > 0, v / np.maximum(c, 1), 0.0).astype(np.float32), (c > 0).astype(np.float32)


# ---------------------------------------------------------------- model


def init_encoder(key):
    params = []
    cin = 3
    for cout in CHANNELS:
        key, k = jax.random.split(key)
        w = jax.random.normal(k, (cout, cin, 3, 3)) * np.sqrt(2.0 / (cin * 9))
        params.append((w, jnp.zeros((cout,))))
        cin = cout
    return params


def encode(params, x):
    for (w, b), s in zip(params, STRIDES):
        x = jax.lax.conv_general_dilated(x, w, (s, s), ((1, 1), (1, 1)),
                                         dimension_numbers=("NCHW", "OIHW", "NCHW"))
        x = jax.nn.relu(x + b[None, :, None, None])
    return x


def slice_features(f, slices):
    """[N, C, H, W] -> [N, S, C*H]: each slice's columns averaged."""
    n, c, h, w = f.shape
    g = f.reshape(n, c, h, slices, w // slices).mean(4)
    return g.transpose(0, 3, 1, 2).reshape(n, slices, c * h)


def adam(params, grads, state, lr, t, b1=0.9, b2=0.999, eps=1e-8):
    m, v = state
    m = jax.tree_util.tree_map(lambda m, g: b1 * m + (1 - b1) * g, m, grads)
    v = jax.tree_util.tree_map(lambda v, g: b2 * v + (1 - b2) * g * g, v, grads)
    params = jax.tree_util.tree_map(
        lambda p, m, v: p - lr * (m / (1 - b1 ** t)) / (jnp.sqrt(v / (1 - b2 ** t)) + eps), params, m, v)
    return params, (m, v)


def adam_state(params):
    z = jax.tree_util.tree_map(jnp.zeros_like, params)
    return (z, z)


def fit(loss_fn, params, batches, val_loss, epochs, patience, lr, label):
    """Adam with early stopping on `val_loss`; returns the best params."""
    grad = jax.jit(jax.value_and_grad(loss_fn))
    state = adam_state(params)
    best, best_params, wait, t = np.inf, params, 0, 0
    for epoch in range(epochs):
        losses = []
        for b in batches(epoch):
            t += 1
            loss, g = grad(params, *b)
            params, state = adam(params, g, state, lr, t)
            losses.append(float(loss))
        v = float(val_loss(params))
        if v < best - 1e-5:
            best, best_params, wait = v, params, 0
        else:
            wait += 1
        progress(label, epoch + 1, epochs, f"train {np.mean(losses):.4f} val {v:.4f} best {best:.4f}")
        if wait >= patience:
            sys.stderr.write(f"\n{label}: early stop after epoch {epoch + 1}\n")
            break
    return best_params, best


def minibatches(n, size, seed):
    rng = np.random.default_rng(seed)
    order = rng.permutation(n)
    return [order[i:i + size] for i in range(0, n, size)]


# ---------------------------------------------------------------- LRN


def lrn_logits(params, x):
    enc, (w, b) = params
    f = encode(enc, x)
    return jnp.einsum("nchw,c->nhw", f, w) + b


def train_lrn(a):
    tr, va = load_dataset(a.train, want_fitam=False), load_dataset(a.val, want_fitam=False)
    ty, tm = pool_labels(tr["lrn_value"], tr["lrn_mask"], 4)
    vy, vm = pool_labels(va["lrn_value"], va["lrn_mask"], 4)
    keep = tr["has_lrn"]
    x, ty, tm = tr["images"][keep], ty[keep], tm[keep]
    pos = float((ty * tm).sum() / max(((1 - ty) * tm).sum(), 1))
    pos_weight = min(1.0 / max(pos, 1e-6), 50.0)
    print(f"LRN: {len(x)} labelled training frames, positive/negative = {pos:.4f}, pos_weight {pos_weight:.1f}")

    def loss_fn(p, xb, yb, mb):
        z = lrn_logits(p, xb)
        bce = jnp.maximum(z, 0) - z * yb + jnp.log1p(jnp.exp(-jnp.abs(z)))
        wgt = mb * (1.0 + (pos_weight - 1.0) * yb)
        return (bce * wgt).sum() / jnp.maximum(wgt.sum(), 1.0)

    key = jax.random.PRNGKey(a.seed)
    params = (init_encoder(key), (jnp.zeros((CHANNELS[-1],)), jnp.array(-2.0)))
    vkeep = va["has_lrn"]
    vx, vy, vm = va["images"][vkeep], vy[vkeep], vm[vkeep]
    vloss = jax.jit(loss_fn)

    def batches(epoch):
        for idx in minibatches(len(x), a.batch, a.seed + epoch):
            yield x[idx], ty[idx], tm[idx]

    params, best = fit(loss_fn, params, batches, lambda p: vloss(p, vx, vy, vm),
                       a.epochs, a.patience, a.lr, "LRN")
    os.makedirs(a.out, exist_ok=True)
    export_lrn(params, tr["options"], a)


# ---------------------------------------------------------------- FITAM


def class_weights(y, w, classes):
    counts = np.array([(w * (y == c)).sum() for c in range(classes)], np.float64)
    inv = np.where(counts > 0, counts.sum() / np.maximum(counts, 1e-9) / classes, 0.0)
    return inv.astype(np.float32)


def weighted_ce(logits, y, w, cw):
    logp = jax.nn.log_softmax(logits, -1)
    yc = jnp.maximum(y, 0)
    nll = -jnp.take_along_axis(logp, yc[..., None], -1)[..., 0]
    wt = w * (y >= 0) * cw[yc]
    return (nll * wt).sum() / jnp.maximum(wt.sum(), 1e-6)


def train_fitam(a):
    tr, va = load_dataset(a.train, want_lrn=False), load_dataset(a.val, want_lrn=False)
    S, R, C, M = tr["slices"], tr["radial"], tr["classes"], a.members
    x, y, w = tr["images"], tr["fit_y"], tr["fit_w"]
    counts = [[int(((y[..., r] == c)).sum()) for c in range(C)] for r in range(R)]
    print(f"FITAM: {len(x)} training frames, labelled swaths per radial bin and class {counts}")
    cw = jnp.asarray(class_weights(y, w, C))
    feat_dim = CHANNELS[-1] * (x.shape[2] // 4)

    # Stage 1: the encoder, with one linear head per radial bin.
    def loss1(p, xb, yb, wb):
        enc, (hw, hb) = p
        f = slice_features(encode(enc, xb), S)  # [N, S, D]
        z = (jnp.einsum("nsd,dk->nsk", f, hw) + hb).reshape(f.shape[0], S, R, C)
        return weighted_ce(z, yb, wb, cw)

    key = jax.random.PRNGKey(a.seed)
    k1, k2 = jax.random.split(key)
    params = (init_encoder(k1), (jax.random.normal(k2, (feat_dim, R * C)) * 0.01, jnp.zeros((R * C,))))
    v1 = jax.jit(loss1)

    def batches(epoch):
        for idx in minibatches(len(x), a.batch, a.seed + epoch):
            yield x[idx], y[idx], w[idx]

    params, _ = fit(loss1, params, batches, lambda p: v1(p, va["images"], va["fit_y"], va["fit_w"]),
                    a.epochs, a.patience, a.lr, "FITAM encoder")
    enc = params[0]

    # Stage 2: frozen features, standardised; M linear members per radial bin.
    feats = jax.jit(lambda xb: slice_features(encode(enc, xb), S))
    F = np.concatenate([np.asarray(feats(x[i:i + 64])) for i in range(0, len(x), 64)])
    mu, sd = F.reshape(-1, feat_dim).mean(0), F.reshape(-1, feat_dim).std(0) + 1e-3
    heads_w = np.zeros((R, M, feat_dim, C), np.float32)
    heads_b = np.zeros((R, M, C), np.float32)
    for r in range(R):
        sel = y[:, :, r] >= 0
        Fr, yr, wr = ((F[sel] - mu) / sd).astype(np.float32), y[:, :, r][sel], w[:, :, r][sel]
        cwr = jnp.asarray(class_weights(yr, wr, C))

        def loss2(p, fb, yb, wb):
            return weighted_ce(fb @ p[0] + p[1], yb, wb, cwr)

        v2 = jax.jit(loss2)
        for m in range(M):
            rng = np.random.default_rng(a.seed * 1000 + r * 100 + m)
            order = rng.permutation(len(Fr))
            cut = int(0.8 * len(order))
            ti, vi = order[:cut], order[cut:]
            if len(vi) == 0 or len(ti) == 0:
                continue

            def b2(epoch, ti=ti):
                for idx in minibatches(len(ti), 256, a.seed + epoch):
                    j = ti[idx]
                    yield Fr[j], yr[j], wr[j]

            p0 = (jnp.zeros((feat_dim, C)), jnp.zeros((C,)))
            p, _ = fit(loss2, p0, b2, lambda p, vi=vi: v2(p, Fr[vi], yr[vi], wr[vi]),
                       a.member_epochs, 10, 1e-3, f"FITAM radial {r} member {m + 1}/{M}")
            heads_w[r, m], heads_b[r, m] = np.asarray(p[0]), np.asarray(p[1])
    os.makedirs(a.out, exist_ok=True)
    export_fitam(enc, heads_w, heads_b, mu, sd, tr["options"], a)


# ---------------------------------------------------------------- HIP

HIP_FEATURES = 64
HIP_HIDDEN = 128
# The paper's training perturbation: Gaussian noise of sigma on every
# future position bounds q from above (its eta); the same sigma is the
# least standard deviation a step may have, so q stays bounded at test
# time too. The paper's 0.01 (`--sigma`) is the default.
HIP_SIGMA = 0.01


def load_hip(folder, limit=None):
    """A `farsight-sim hip-dataset` folder: uint8 images [N, 3, H, W] (as
    the inference stage resizes the camera), futures [N, H, 2] and past
    positions [N, P, 2] (m, robot frame, the past oldest first) and, where
    the folder has them, which library trajectories are free of lethal
    cells from each pose ([N, K] bool, else None)."""
    import tomllib
    from PIL import Image

    with open(os.path.join(folder, "hip-dataset.toml"), "rb") as f:
        m = tomllib.load(f)
    rows = list(csv.reader(open(os.path.join(folder, "examples.csv"))))[1:]
    if limit:
        rows = rows[:limit]
    n, H, P = len(rows), m["horizon"], m["past"]
    h, w = m["image_height"], m["image_width"]
    images = np.zeros((n, 3, h, w), np.uint8)
    futures = np.zeros((n, H, 2), np.float32)
    past = np.zeros((n, P, 2), np.float32)
    header = open(os.path.join(folder, "examples.csv")).readline().strip().split(",")
    free = None
    if header[-1] == "library_free" and rows:
        free = np.zeros((n, len(rows[0][-1])), bool)
    for i, r in enumerate(rows):
        images[i] = np.asarray(Image.open(os.path.join(folder, "images", f"{int(r[0]):06d}.png"))
                               .convert("RGB")).transpose(2, 0, 1)
        futures[i] = np.array(r[6:6 + 2 * H], np.float32).reshape(H, 2)
        past[i] = np.array(r[6 + 2 * H:6 + 2 * H + 2 * P], np.float32).reshape(P, 2)
        if free is not None:
            free[i] = np.frombuffer(r[-1].encode(), np.uint8) == ord("1")
        if i % 2000 == 0 or i == n - 1:
            progress(f"loading {os.path.basename(folder.rstrip('/'))}", i + 1, n)
    return dict(manifest=m, images=images, futures=futures, past=past.reshape(n, 2 * P), free=free)


def hip_steps(futures):
    """Future positions [..., H, 2] -> (the positions before each step,
    flattened and masked to those already taken [..., H, 2H]; each step's
    displacement [..., H, 2])."""
    H = futures.shape[-2]
    before = jnp.concatenate([jnp.zeros_like(futures[..., :1, :]), futures[..., :-1, :]], -2)
    mask = (jnp.arange(H)[None, :] < jnp.arange(H)[:, None]).astype(futures.dtype)  # [t, j]: j < t
    prev = (futures[..., None, :, :] * mask[..., None]).reshape(futures.shape[:-2] + (H, 2 * H))
    return prev, futures - before


def hip_init(key, h, w, H, P, components):
    k = jax.random.split(key, 6)
    flat = CHANNELS[-1] * (h // 8) * (w // 8)
    dense = lambda k, i, o: (jax.random.normal(k, (i, o)) * np.sqrt(2.0 / i), jnp.zeros((o,)))  # noqa: E731
    return dict(
        enc=init_encoder(k[0]),
        feat=dense(k[1], flat, HIP_FEATURES),
        past=(jax.random.normal(k[5], (2 * P, HIP_FEATURES)) * np.sqrt(2.0 / max(2 * P, 1)),),
        w1=dense(k[2], HIP_FEATURES + 3 * H, HIP_HIDDEN),
        # Per step and mixture component: a logit, a mean and a raw
        # deviation per axis; the means start spread round the origin.
        w2=(jax.random.normal(k[3], (HIP_HIDDEN, 5 * components)) * 0.01,
            jnp.concatenate([jnp.zeros(components),
                             jax.random.normal(k[4], (2 * components,)) * 0.05,
                             jnp.zeros(2 * components)])),
    )


def hip_features(p, x, past):
    """Images [N, 3, h, w] in 0..1 and past positions [N, 2P] -> [N, F]:
    the encoder, 2x2 average pooling (the layout of what is where stays),
    and one dense layer over the image's cells and the past."""
    f = encode(p["enc"], x)
    n, c, fh, fw = f.shape
    f = f.reshape(n, c, fh // 2, 2, fw // 2, 2).mean((3, 5)).reshape(n, -1)
    return jax.nn.relu(f @ p["feat"][0] + past @ p["past"][0] + p["feat"][1])


def hip_log_q(p, feat, futures, sigma_min=HIP_SIGMA):
    """log q(tau | o) of futures [N, ..., H, 2] under features [N, F]: an
    autoregressive density over each step's displacement given the image
    and the steps before (R2P2 / Deep Imitative Models' factorisation;
    displacements to positions has unit Jacobian), each step a mixture of
    diagonal Gaussians: sticky random turn rates are spread evenly, and
    an obstacle in view takes a notch out of them, which one Gaussian per
    step cannot show."""
    H = futures.shape[-2]
    prev, d = hip_steps(futures)
    onehot = jnp.broadcast_to(jnp.eye(H, dtype=futures.dtype), prev.shape[:-1] + (H,))
    w1, b1 = p["w1"]
    F = feat.shape[-1]
    extra = prev.ndim - 2 - 1  # axes between the batch and the steps
    fw = (feat @ w1[:F]).reshape((feat.shape[0],) + (1,) * (extra + 1) + (HIP_HIDDEN,))
    hdn = jax.nn.relu(fw + jnp.concatenate([prev, onehot], -1) @ w1[F:] + b1)
    out = hdn @ p["w2"][0] + p["w2"][1]
    M = out.shape[-1] // 5
    logw = jax.nn.log_softmax(out[..., :M], -1)
    mu = out[..., M:3 * M].reshape(out.shape[:-1] + (M, 2))
    sigma = sigma_min + jax.nn.softplus(out[..., 3 * M:]).reshape(out.shape[:-1] + (M, 2))
    z = (d[..., None, :] - mu) / sigma
    comp = (-0.5 * z * z - jnp.log(sigma)).sum(-1) - np.log(2 * np.pi)
    return jax.nn.logsumexp(logw + comp, -1).sum(-1)


def read_library(path):
    import tomllib

    with open(path, "rb") as f:
        lib = tomllib.load(f)
    return np.array(lib["trajectories"], np.float32), lib["step_s"]


def train_hip(a):
    tr, va = load_hip(a.train, a.limit), load_hip(a.val)
    lib, step_s = read_library(a.library)
    H = tr["futures"].shape[1]
    if lib.shape[1] != H or abs(step_s - tr["manifest"]["step_s"]) > 1e-9:
        raise SystemExit(f"{a.library}: trajectories of {lib.shape[1]} points {step_s} s apart, "
                         f"the dataset's futures {H} points {tr['manifest']['step_s']} s apart")
    for name, d in [("--train", tr), ("--val", va)]:
        if d["free"] is not None and d["free"].shape[1] != len(lib):
            raise SystemExit(f"{name}: library_free judges {d['free'].shape[1]} trajectories, "
                             f"{a.library} holds {len(lib)}: made with another library")
    h, w = tr["images"].shape[2:]
    if h % 8 or w % 8:
        raise SystemExit(f"{a.train}: {w}x{h} images; HIP's encoder and pooling want sides divisible by 8")
    print(f"HIP: {len(tr['images'])} training examples, {len(va['images'])} validation, "
          f"{h}x{w} images, {tr['past'].shape[1] // 2} past and H = {H} future points, library K = {len(lib)}")
    noise = np.random.default_rng(a.seed)

    def loss_fn(p, xb, pb, fb):
        return -hip_log_q(p, hip_features(p, xb, pb), fb, a.sigma).mean()

    P = tr["past"].shape[1] // 2
    params = hip_init(jax.random.PRNGKey(a.seed), h, w, H, P, a.components)
    vloss = jax.jit(loss_fn)
    val_idx = np.arange(min(len(va["images"]), 4000))

    def val_loss(p):
        ls = [vloss(p, va["images"][i:i + 256] / np.float32(255), va["past"][i:i + 256], va["futures"][i:i + 256])
              for i in range(0, len(val_idx), 256)]
        return np.mean([float(v) for v in ls])

    def batches(epoch):
        for idx in minibatches(len(tr["images"]), a.batch, a.seed + epoch):
            f = tr["futures"][idx]
            yield (tr["images"][idx] / np.float32(255), tr["past"][idx],
                   f + noise.normal(0, a.sigma, f.shape).astype(np.float32))

    params, best = fit(loss_fn, params, batches, val_loss, a.epochs, a.patience, a.lr, "HIP")
    os.makedirs(a.out, exist_ok=True)
    export_hip(params, lib, tr["manifest"], a)
    # What the learned term does with the library: how highly it ranks the
    # library trajectory nearest each held-out future, against ranking by
    # how often each trajectory is nearest in the training set (no image).
    sets = [("validation", va)] + [(os.path.basename(d.rstrip("/")), load_hip(d)) for d in a.report or []]
    report = hip_report(a.out, lib, tr["futures"], sets)
    with open(os.path.join(a.out, "metrics.md"), "w") as f:
        f.write(f"validation negative log-likelihood per example: {best:.2f}\n\n{report}\n")
    print(report)


def hip_report_cmd(a):
    lib, _ = read_library(a.library)
    prior = load_hip(a.prior, a.limit)["futures"]
    sets = [(os.path.basename(d.rstrip("/")), load_hip(d)) for d in a.data]
    for name, d in sets:
        if d["free"] is not None and d["free"].shape[1] != len(lib):
            raise SystemExit(f"{name}: library_free judges {d['free'].shape[1]} trajectories, "
                             f"{a.library} holds {len(lib)}: made with another library")
    print(hip_report(a.model, lib, prior, sets))


def nearest_library(lib, futures):
    d = ((futures[:, None] - lib[None]) ** 2).sum((-1, -2))
    return d.argmin(1)


def pairwise_auc(score, label):
    """Per row: P(a free trajectory scores above a lethal one), ties half;
    NaN where a row has only one kind."""
    out = np.full(len(score), np.nan)
    for i in range(0, len(score), 256):
        s, y = score[i:i + 256], label[i:i + 256]
        gt = (s[:, :, None] > s[:, None, :]) + 0.5 * (s[:, :, None] == s[:, None, :])
        pair = y[:, :, None] & ~y[:, None, :]
        n = pair.sum((1, 2))
        out[i:i + 256] = np.where(n > 0, (gt * pair).sum((1, 2)) / np.maximum(n, 1), np.nan)
    return out


def hip_report(model_dir, lib, prior_futures, sets):
    """How the learned term ranks the library where it is used, against
    the same ranking without the image (how often each trajectory is the
    nearest to a training future): on each set whose examples say which
    library trajectories are free of lethal cells from the pose, the mean
    per-example AUROC of free above lethal, and how often the likeliest
    trajectory is free; and how highly the trajectory nearest the future
    actually driven ranks."""
    prior = np.bincount(nearest_library(lib, prior_futures), minlength=len(lib)).astype(np.float64)
    rows = ["| set | ranking | free above lethal (mean AUROC) | likeliest is free | nearest to the driven future: median rank, top 10 |",
            "|---|---|---|---|---|"]
    for name, va in sets:
        # The exported model, as the subgoal stage runs it.
        logq = run_onnx(model_dir, va["images"], scale=np.float32(1 / 255), past=va["past"])
        near = nearest_library(lib, va["futures"])
        for how, sc in [("learned log q(tau | o)", logq),
                        ("training frequency (no image)", np.broadcast_to(prior, logq.shape))]:
            r = (sc > sc[np.arange(len(sc)), near][:, None]).sum(1)
            free = va.get("free")
            if free is not None:
                auc = np.nanmean(pairwise_auc(sc, free))
                top = free[np.arange(len(sc)), sc.argmax(1)].mean()
                judged = f"{auc:.3f} | {100 * top:.1f}%"
            else:
                judged = "- | -"
            rows.append(f"| {name} ({len(sc)}) | {how} | {judged} | "
                        f"{np.median(r):.0f} of {len(lib)}, {100 * (r < 10).mean():.0f}% |")
        if va.get("free") is not None:
            rows.append(f"| {name} | (free share) | {100 * va['free'].mean():.1f}% of the library is free | | |")
    return "\n".join(rows)


def export_hip(params, lib, manifest, a):
    """ONNX: images [1, 3, h, w] -> log_q [1, K], the library's K
    trajectories scored in one pass. What depends on the library alone (the
    first layer's share of each step's history) is folded into constants."""
    from onnx import TensorProto, helper, numpy_helper

    K, H, _ = lib.shape
    P = manifest["past"]
    h, w = manifest["image_height"], manifest["image_width"]
    F = HIP_FEATURES
    prev, d = hip_steps(jnp.asarray(lib))
    onehot = np.broadcast_to(np.eye(H, dtype=np.float32), (K, H, H))
    w1, b1 = (np.asarray(v) for v in params["w1"])
    const = (np.concatenate([np.asarray(prev), onehot], -1) @ w1[F:] + b1).reshape(K * H, HIP_HIDDEN)
    nodes, inits = [], []
    cur = onnx_encoder(helper, numpy_helper, params["enc"], nodes, inits)
    arr = lambda v, name: inits.append(numpy_helper.from_array(np.asarray(v, np.float32), name))  # noqa: E731
    i64 = lambda v, name: inits.append(numpy_helper.from_array(np.array(v, np.int64), name))  # noqa: E731
    arr(params["feat"][0], "feat.w")
    arr(params["past"][0], "past.w")
    arr(params["feat"][1], "feat.b")
    arr(w1[:F], "w1.feat")
    arr(const, "w1.library")
    arr(params["w2"][0], "w2.w")
    arr(params["w2"][1], "w2.b")
    M = np.asarray(params["w2"][0]).shape[1] // 5
    arr(np.asarray(d).reshape(K * H, 1, 2), "steps")
    arr([a.sigma], "sigma_min")
    arr([np.log(2 * np.pi)], "log_2pi")
    arr([-0.5], "minus_half")
    i64([M, 2 * M, 2 * M], "split3")
    i64([K * H, M, 2], "khm2")
    i64([1, K, H], "kh")
    i64([2], "axis2")
    nodes += [
        helper.make_node("AveragePool", [cur], ["pooled"], kernel_shape=[2, 2], strides=[2, 2]),
        helper.make_node("Flatten", ["pooled"], ["flat"], axis=1),
        helper.make_node("MatMul", ["flat", "feat.w"], ["f0"]),
        helper.make_node("MatMul", ["past", "past.w"], ["fp"]),
        helper.make_node("Add", ["f0", "fp"], ["f0p"]),
        helper.make_node("Add", ["f0p", "feat.b"], ["f1"]),
        helper.make_node("Relu", ["f1"], ["feat"]),
        helper.make_node("MatMul", ["feat", "w1.feat"], ["h0"]),
        helper.make_node("Add", ["h0", "w1.library"], ["h1"]),
        helper.make_node("Relu", ["h1"], ["h2"]),
        helper.make_node("MatMul", ["h2", "w2.w"], ["o0"]),
        helper.make_node("Add", ["o0", "w2.b"], ["o1"]),
        helper.make_node("Split", ["o1", "split3"], ["logits", "mu0", "raw"], axis=1),
        helper.make_node("LogSoftmax", ["logits"], ["logw"], axis=1),
        helper.make_node("Reshape", ["mu0", "khm2"], ["mu"]),
        helper.make_node("Softplus", ["raw"], ["sp"]),
        helper.make_node("Add", ["sp", "sigma_min"], ["sigma0"]),
        helper.make_node("Reshape", ["sigma0", "khm2"], ["sigma"]),
        helper.make_node("Sub", ["steps", "mu"], ["dm"]),
        helper.make_node("Div", ["dm", "sigma"], ["z"]),
        helper.make_node("Mul", ["z", "z"], ["z2"]),
        helper.make_node("Mul", ["z2", "minus_half"], ["q0"]),
        helper.make_node("Log", ["sigma"], ["ls"]),
        helper.make_node("Sub", ["q0", "ls"], ["q1"]),
        helper.make_node("ReduceSum", ["q1", "axis2"], ["q2"], keepdims=0),
        helper.make_node("Sub", ["q2", "log_2pi"], ["comp"]),
        helper.make_node("Add", ["comp", "logw"], ["wc"]),
        helper.make_node("ReduceLogSumExp", ["wc"], ["step"], axes=[1], keepdims=0),
        helper.make_node("Reshape", ["step", "kh"], ["q3"]),
        helper.make_node("ReduceSum", ["q3", "axis2"], ["log_q"], keepdims=0),
    ]
    graph = helper.make_graph(
        nodes, "farsight_hip",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, h, w]),
         helper.make_tensor_value_info("past", TensorProto.FLOAT, [1, 2 * P])],
        [helper.make_tensor_value_info("log_q", TensorProto.FLOAT, [1, K])], inits)
    path = os.path.join(a.out, "model.onnx")
    save_model(graph, path)
    libj = jnp.asarray(lib)
    past = np.random.default_rng(1).normal(0, 1, (1, 2 * P)).astype(np.float32)
    check_onnx(path, lambda x: np.asarray(hip_log_q(params, hip_features(params, x, past), libj[None], a.sigma)),
               (1, 3, h, w), {"past": past})
    write_model_config(a, f"""# HIP's learned density (farsight_train.py hip): log q(tau | image, past) of each of
# the K = {K} trajectories of the library it was exported with, H = {H} points
# {manifest['step_s']} s apart, given the image and the robot's {P} past positions
# (`past_input`); autoregressive over each step given those and the steps
# before (Deep Imitative Models' factorisation), each step a mixture of {M}
# Gaussians, on a 4-layer CPU encoder. Use it with that library.
""", w, h, f"""[past_input]
name = "past"
points = {P}
step_s = {manifest['step_s']}

[[outputs]]
name = "log_q"
kind = "trajectory_log_likelihood"
classes = {K}
""")
    print(f"HIP model: {path} ({os.path.getsize(path) / 1e3:.0f} kB)")


# ---------------------------------------------------------------- export


def onnx_encoder(helper, numpy_helper, enc, nodes, inits):
    cur = "images"
    for i, ((w, b), s) in enumerate(zip(enc, STRIDES)):
        inits += [numpy_helper.from_array(np.asarray(w, np.float32), f"conv{i}.w"),
                  numpy_helper.from_array(np.asarray(b, np.float32), f"conv{i}.b")]
        nodes.append(helper.make_node("Conv", [cur, f"conv{i}.w", f"conv{i}.b"], [f"c{i}"],
                                      kernel_shape=[3, 3], pads=[1, 1, 1, 1], strides=[s, s]))
        nodes.append(helper.make_node("Relu", [f"c{i}"], [f"r{i}"]))
        cur = f"r{i}"
    return cur


def save_model(graph, path):
    import onnx
    from onnx import helper

    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="farsight-train")
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, path)


INPUT_SECTION = """
[input]
name = "images"
layout = "nchw"
width = {width}
height = {height}
resize = "bilinear"
color = "rgb"
scale = 0.00392156862745098
mean = [0.0, 0.0, 0.0]
std = [1.0, 1.0, 1.0]
"""


def write_model_config(a, comment, width, height, outputs):
    """The model.toml the inference stage reads: what the model is
    (`comment`, TOML comment lines), how it was trained, its input and its
    outputs."""
    with open(os.path.join(a.out, "model.toml"), "w") as f:
        f.write(f"""{comment}# Trained by: {provenance(a)}
model = "model.onnx"
execution_provider = "cpu"
threads = 1
{INPUT_SECTION.format(width=width, height=height)}
{outputs}""")


def provenance(a):
    return " ".join(["python", "tools/train/farsight_train.py"] + sys.argv[1:])


def export_lrn(params, o, a):
    from onnx import TensorProto, helper, numpy_helper

    enc, (w, b) = params
    h, wd = o["image_height"], o["image_width"]
    nodes, inits = [], []
    cur = onnx_encoder(helper, numpy_helper, enc, nodes, inits)
    inits += [numpy_helper.from_array(np.asarray(w, np.float32).reshape(1, -1, 1, 1), "head.w"),
              numpy_helper.from_array(np.asarray(b, np.float32).reshape(1), "head.b")]
    nodes.append(helper.make_node("Conv", [cur, "head.w", "head.b"], ["heatmap"], kernel_shape=[1, 1]))
    graph = helper.make_graph(
        nodes, "farsight_lrn",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, h, wd])],
        [helper.make_tensor_value_info("heatmap", TensorProto.FLOAT, [1, 1, h // 4, wd // 4])], inits)
    path = os.path.join(a.out, "model.onnx")
    save_model(graph, path)
    check_onnx(path, lambda x: np.asarray(lrn_logits(params, x))[:, None], (1, 3, h, wd))
    write_model_config(a, f"""# LRN affordance heatmap (farsight_train.py lrn): a 4-layer CPU encoder and a
# 1x1 head; one logit per 4x4 pixels, sigmoid applied by the inference stage.
""", wd, h, f"""[[outputs]]
name = "heatmap"
kind = "affordance_heatmap"
layout = "nchw"
classes = 1
activation = "sigmoid"
""")
    print(f"LRN model: {path} ({os.path.getsize(path) / 1e3:.0f} kB)")


def export_fitam(enc, heads_w, heads_b, mu, sd, o, a):
    from onnx import TensorProto, helper, numpy_helper

    R, M, D, C = heads_w.shape
    S = o["slices"]
    h, wd = o["image_height"], o["image_width"]
    fh, fw = h // 4, wd // 4
    # Fold the standardisation into the members: z = ((f - mu) / sd) W + b.
    W = (heads_w / sd[None, None, :, None]).transpose(2, 0, 1, 3).reshape(D, R * M * C)
    B = (heads_b - np.einsum("d,rmdc->rmc", mu / sd, heads_w)).reshape(R * M * C)
    nodes, inits = [], []
    cur = onnx_encoder(helper, numpy_helper, enc, nodes, inits)
    shp = lambda name, v: inits.append(numpy_helper.from_array(np.array(v, np.int64), name))  # noqa: E731
    shp("s5", [1, CHANNELS[-1], fh, S, fw // S])
    shp("s2", [S, D])
    shp("out", [1, S, R, M, C])
    inits += [numpy_helper.from_array(W.astype(np.float32), "members.w"),
              numpy_helper.from_array(B.astype(np.float32), "members.b")]
    nodes += [
        helper.make_node("Reshape", [cur, "s5"], ["g5"]),
        helper.make_node("ReduceMean", ["g5"], ["g4"], axes=[4], keepdims=0),
        helper.make_node("Transpose", ["g4"], ["gt"], perm=[0, 3, 1, 2]),
        helper.make_node("Reshape", ["gt", "s2"], ["f"]),
        helper.make_node("MatMul", ["f", "members.w"], ["z"]),
        helper.make_node("Add", ["z", "members.b"], ["zb"]),
        helper.make_node("Reshape", ["zb", "out"], ["far_field"]),
    ]
    graph = helper.make_graph(
        nodes, "farsight_fitam",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, h, wd])],
        [helper.make_tensor_value_info("far_field", TensorProto.FLOAT, [1, S, R, M, C])], inits)
    path = os.path.join(a.out, "model.onnx")
    save_model(graph, path)

    def reference(x):
        f = (np.asarray(slice_features(encode(enc, x), S))[0] - mu) / sd
        return np.einsum("sd,rmdc->srmc", f, heads_w)[None] + heads_b[None, None]

    check_onnx(path, reference, (1, 3, h, wd))
    f = o["fitam"]
    write_model_config(a, f"""# FITAM far-field ensemble (farsight_train.py fitam): a 4-layer CPU encoder,
# {S} image slices, {M} linear members per radial bin; logits
# [1, slices, radial bins, members, classes]. Radial edges {f['range_edges_m']} m,
# class speeds {f['class_speeds_mps']} m/s (bin-projection's config must match).
""", wd, h, f"""[[outputs]]
name = "far_field"
kind = "far_field_ensemble"
ensemble_shape = [{S}, {R}, {M}, {C}]
""")
    print(f"FITAM model: {path} ({os.path.getsize(path) / 1e3:.0f} kB)")


def check_onnx(path, reference, shape, extra=None):
    """The exported graph must compute what the trained model computes
    (`extra`: inputs besides the image, fixed)."""
    import onnxruntime as ort

    x = np.random.default_rng(0).random(shape, dtype=np.float32)
    s = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    got = s.run(None, {"images": x, **(extra or {})})[0]
    want = reference(x)
    # Relative where values are large (HIP's log-likelihoods run to
    # hundreds): float32 sums differ in their last digits there.
    err = float((np.abs(got - want) / np.maximum(1.0, np.abs(want))).max())
    if not err < 1e-3:
        raise SystemExit(f"{path}: ONNX output differs from the trained model by {err}")
    print(f"{path}: ONNX Runtime matches the trained model (max |diff| {err:.2e}, relative above 1)")


# ---------------------------------------------------------------- evaluation


def roc_auc(score, label, weight=None):
    """Area under the ROC curve (ties counted half)."""
    score, label = np.asarray(score, np.float64), np.asarray(label, bool)
    weight = np.ones_like(score) if weight is None else np.asarray(weight, np.float64)
    order = np.argsort(-score, kind="mergesort")
    s, l, w = score[order], label[order], weight[order]
    tp, fp = np.cumsum(w * l), np.cumsum(w * ~l)
    distinct = np.r_[np.nonzero(np.diff(s))[0], len(s) - 1]
    tpr = np.r_[0, tp[distinct]] / max(tp[-1], 1e-12)
    fpr = np.r_[0, fp[distinct]] / max(fp[-1], 1e-12)
    return float(np.trapezoid(tpr, fpr)), fpr, tpr


def best_f1(score, label):
    order = np.argsort(-score, kind="mergesort")
    s, l = score[order], label[order].astype(bool)
    tp, fp = np.cumsum(l), np.cumsum(~l)
    P, N = l.sum(), (~l).sum()
    prec, rec = tp / np.maximum(tp + fp, 1), tp / max(P, 1)
    f1 = 2 * prec * rec / np.maximum(prec + rec, 1e-12)
    i = int(np.argmax(f1))
    return dict(threshold=float(s[i]), F1=float(f1[i]), precision=float(prec[i]), recall=float(rec[i]),
                FPR=float(fp[i] / max(N, 1)), FNR=float(1 - rec[i])), prec, rec


def run_onnx(folder, images, scale=None, past=None):
    """The folder's model.onnx on each image; `scale` multiplies each one
    first (uint8 images stay uint8 in memory); `past`, HIP's past
    positions per image, goes to the input named "past"."""
    import onnxruntime as ort

    s = ort.InferenceSession(os.path.join(folder, "model.onnx"), providers=["CPUExecutionProvider"])
    name = s.get_inputs()[0].name
    out = []
    for i in range(len(images)):
        x = images[i:i + 1] if scale is None else images[i:i + 1].astype(np.float32) * scale
        feed = {name: x} if past is None else {name: x, "past": past[i:i + 1]}
        out.append(s.run(None, feed)[0][0])
        if i % 50 == 0 or i == len(images) - 1:
            progress(f"running {os.path.basename(folder.rstrip('/'))}", i + 1, len(images))
    return np.stack(out)


def evaluate(a):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = load_dataset(a.data)
    os.makedirs(a.out, exist_ok=True)
    report = {}
    lines = [f"held-out set: {a.data} ({len(d['images'])} frames)", ""]
    if a.lrn:
        keep = d["has_lrn"]
        z = run_onnx(a.lrn, d["images"][keep])[:, 0]
        p = 1 / (1 + np.exp(-z))
        y, m = pool_labels(d["lrn_value"][keep], d["lrn_mask"][keep], 4)
        sel = m > 0
        score, label = p[sel], y[sel] >= 0.15
        auc, fpr, tpr = roc_auc(score, label)
        best, prec, rec = best_f1(score, label)
        report["lrn"] = dict(AUROC=auc, frames=int(keep.sum()), cells=int(sel.sum()),
                             positives=int(label.sum()), **best)
        lines += ["LRN affordance (LRN Table II: targets binarised at 0.15, best-F1 threshold)", "",
                  "| metric | farsight (sim, held-out) | LRN Auto, Racer Heavy | LRN Auto, Spot | LRN Hand, Racer Heavy |",
                  "|---|---|---|---|---|"]
        paper = dict(AUROC=(0.63, 0.93, 0.84), F1=(0.11, 0.10, 0.52), precision=(0.08, 0.06, 0.51),
                     recall=(0.17, 0.35, 0.52), FPR=(0.03, 0.01, 0.01), FNR=(0.83, 0.65, 0.48))
        for k, v in paper.items():
            lines.append(f"| {k} | {report['lrn'][k]:.2f} | {v[0]:.2f} | {v[1]:.2f} | {v[2]:.2f} |")
        lines.append(f"\n({report['lrn']['cells']} labelled output cells, {report['lrn']['positives']} positive, "
                     f"best threshold {best['threshold']:.2f})\n")
        fig, ax = plt.subplots(1, 2, figsize=(9, 4))
        ax[0].plot(fpr, tpr)
        ax[0].plot([0, 1], [0, 1], "k:", lw=0.5)
        ax[0].set(title=f"LRN ROC (AUROC {auc:.2f})", xlabel="false positive rate", ylabel="true positive rate")
        ax[1].plot(rec, prec)
        ax[1].set(title=f"LRN precision-recall (best F1 {best['F1']:.2f})", xlabel="recall", ylabel="precision")
        fig.tight_layout()
        fig.savefig(os.path.join(a.out, "lrn_roc_pr.png"), dpi=110)
        plt.close(fig)
    if a.fitam:
        z = run_onnx(a.fitam, d["images"])
        z = z - z.max(-1, keepdims=True)
        p = (np.exp(z) / np.exp(z).sum(-1, keepdims=True)).mean(3)  # [N, S, R, C]
        R, C = d["radial"], d["classes"]
        edges = d["options"]["fitam"]["range_edges_m"]
        lines += ["FITAM far-field classes (FITAM Table IV: class-weighted one-vs-rest ROC AUC)", "",
                  "| radial bin | swaths | per class | class-weighted ROC AUC | accuracy |", "|---|---|---|---|---|"]
        fig, axes = plt.subplots(1, R, figsize=(4 * R, 4), squeeze=False)
        report["fitam"] = []
        cost = 1 / np.asarray(d["options"]["fitam"]["class_speeds_mps"], dtype=float)
        cost_rows = []
        for r in range(R):
            y = d["fit_y"][:, :, r]
            sel = y >= 0
            yr, pr = y[sel], p[:, :, r][sel]
            aucs, support = [], []
            for c in range(C):
                if 0 < (yr == c).sum() < len(yr):
                    auc_c, fpr, tpr = roc_auc(pr[:, c], yr == c)
                    aucs.append(auc_c)
                    support.append((yr == c).sum())
                    axes[0][r].plot(fpr, tpr, label=f"class {c} (AUC {auc_c:.2f})")
            wauc = float(np.average(aucs, weights=support)) if aucs else float("nan")
            acc = float((pr.argmax(-1) == yr).mean()) if len(yr) else float("nan")
            counts = [int((yr == c).sum()) for c in range(C)]
            # What the planner is handed: a swath's measured cost by its true
            # class, for FITAM's rule (the most likely class's cost) and for
            # bin projection's `measurement = "expected_cost"` (sum of p / speed).
            measured = dict(most_likely=cost[pr.argmax(-1)], expected=pr @ cost)
            means = {k: [float(z[yr == c].mean()) if (yr == c).any() else None for c in range(C)]
                     for k, z in measured.items()}
            cells = [f"{m:.2f} / {e:.2f}" if m is not None else "-"
                     for m, e in zip(means["most_likely"], means["expected"])]
            mae = " / ".join(f"{np.abs(z - cost[yr]).mean():.2f}" for z in measured.values())
            cost_rows.append(f"| {edges[r]:.0f}-{edges[r + 1]:.0f} m | " + " | ".join(cells) + f" | {mae} |")
            report["fitam"].append(dict(radial_bin=r, swaths=int(len(yr)), counts=counts, auc=wauc, accuracy=acc,
                                        measured_cost=means))
            lines.append(f"| {edges[r]:.0f}-{edges[r + 1]:.0f} m | {len(yr)} | {counts} | {wauc:.2f} | {acc:.2f} |")
            axes[0][r].plot([0, 1], [0, 1], "k:", lw=0.5)
            axes[0][r].set(title=f"FITAM {edges[r]:.0f}-{edges[r + 1]:.0f} m (AUC {wauc:.2f})",
                           xlabel="false positive rate", ylabel="true positive rate")
            axes[0][r].legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(os.path.join(a.out, "fitam_roc.png"), dpi=110)
        plt.close(fig)
        lines.append("\nFITAM's paper (real robot, 43-64 m bin, 15 members): summer test .94-.97, "
                     "fall .58-.63, winter .67-.74 (DinoV2 / ResNet-18 / no pre-training).\n")
        lines += ["Measured cost (s/m) by true class, mean over held-out swaths: most likely class / expected cost", "",
                  "| radial bin | " + " | ".join(f"true {c:.3f}" for c in cost) + " | mean abs error |",
                  "|---|" + "---|" * (len(cost) + 1)] + cost_rows + [""]
    text = "\n".join(lines)
    print(text)
    with open(os.path.join(a.out, "metrics.md"), "w") as f:
        f.write(text + "\n")
    with open(os.path.join(a.out, "metrics.json"), "w") as f:
        json.dump(report, f, indent=2)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    for name in ["lrn", "fitam"]:
        s = sub.add_parser(name)
        s.add_argument("--train", required=True)
        s.add_argument("--val", required=True)
        s.add_argument("--out", required=True)
        s.add_argument("--epochs", type=int, default=40)
        s.add_argument("--patience", type=int, default=10)
        s.add_argument("--batch", type=int, default=32)
        s.add_argument("--lr", type=float, default=2e-3)
        s.add_argument("--seed", type=int, default=1)
        if name == "fitam":
            s.add_argument("--members", type=int, default=15)
            s.add_argument("--member-epochs", type=int, default=200)
    h = sub.add_parser("hip")
    h.add_argument("--train", required=True, help="a `farsight-sim hip-dataset` folder")
    h.add_argument("--val", required=True)
    h.add_argument("--library", required=True, help="the HIP library the model scores (hip-library.toml)")
    h.add_argument("--out", required=True)
    h.add_argument("--epochs", type=int, default=10)
    h.add_argument("--patience", type=int, default=3)
    h.add_argument("--batch", type=int, default=32)
    h.add_argument("--lr", type=float, default=1e-3)
    h.add_argument("--seed", type=int, default=1)
    h.add_argument("--limit", type=int, help="use only the first N training examples")
    h.add_argument("--report", nargs="*", help="more hip-dataset folders to report on (e.g. the novel world)")
    h.add_argument("--components", type=int, default=5, help="Gaussians per step's mixture")
    h.add_argument("--sigma", type=float, default=HIP_SIGMA,
                   help="training perturbation and least step deviation, m (the paper: 0.01)")
    hr = sub.add_parser("hip-report", help="judge an exported HIP model on hip-dataset folders")
    hr.add_argument("--model", required=True, help="the folder of model.onnx")
    hr.add_argument("--library", required=True)
    hr.add_argument("--prior", required=True, help="a hip-dataset folder for the no-image ranking (the training set)")
    hr.add_argument("--data", nargs="+", required=True)
    hr.add_argument("--limit", type=int, help="use only the first N examples of --prior")
    e = sub.add_parser("evaluate")
    e.add_argument("--data", required=True)
    e.add_argument("--lrn")
    e.add_argument("--fitam")
    e.add_argument("--out", required=True)
    a = p.parse_args()
    t = time.time()
    {"lrn": train_lrn, "fitam": train_fitam, "hip": train_hip, "hip-report": hip_report_cmd,
     "evaluate": evaluate}[a.cmd](a)
    print(f"{a.cmd} done in {time.time() - t:.0f} s")


if __name__ == "__main__":
    main()
