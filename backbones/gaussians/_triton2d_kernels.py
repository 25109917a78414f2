"""The Triton kernels of :mod:`.triton2d` (imported on first use: importing triton takes a second).

Pixel lanes: a program is one camera-tile; lane ``r`` is its pixel ``(r % TILE, r // TILE)`` (``BLOCK``: the power of
two from ``TILE * TILE`` up; the lanes past it idle). A pair's 21 table
values are scalar loads (every lane reads the same entry); per-pixel state lives in registers.
Only what Triton compiles is used (no ``break``: the forward's early stop is the ``while`` condition).
"""
import triton
import triton.language as tl

BATCH = tl.constexpr(32)  # pairs the forward composites between two counts of its live pixels


@triton.jit
def _hit(tab, s, px, py, lp, near, NCOL: tl.constexpr, MAX_ALPHA_: tl.constexpr, MIN_ALPHA_: tl.constexpr):
    """Entry ``s`` on the lanes' pixel centres ``(px, py)``: what cpp/composite2d.h's ``eval2`` computes."""
    row = tab + s * NCOL
    a0, a1, a2 = tl.load(row + 0), tl.load(row + 1), tl.load(row + 2)
    b0, b1, b2 = tl.load(row + 3), tl.load(row + 4), tl.load(row + 5)
    c0, c1, c2 = tl.load(row + 6), tl.load(row + 7), tl.load(row + 8)
    cx, cy, op = tl.load(row + 9), tl.load(row + 10), tl.load(row + 11)
    tz0, tz1, tz2 = tl.load(row + 12), tl.load(row + 13), tl.load(row + 14)
    q0 = px * a0 + py * b0 + c0
    q1 = px * a1 + py * b1 + c1
    q2 = px * a2 + py * b2 + c2
    nz = q2 != 0
    ip = tl.where(nz, 1.0 / tl.where(nz, q2, 1.0), 0.0)
    u = q0 * ip
    v = q1 * ip
    rho3d = u * u + v * v
    dx = cx - px
    dy = cy - py
    rho2d = lp * (dx * dx + dy * dy)
    use3d = rho3d <= rho2d
    z = tl.where(use3d, u * tz0 + v * tz1 + tz2, tz2)
    power = -0.5 * tl.where(use3d, rho3d, rho2d)
    g = tl.exp(power)
    alpha = tl.minimum(op * g, MAX_ALPHA_)
    ok = nz & (z >= near) & (power <= 0) & (alpha >= MIN_ALPHA_)
    return u, v, ip, dx, dy, z, g, alpha, op, use3d, ok, tz0, tz1


@triton.jit
def _tile_lanes(pid, TX, TY, W, H, TILE: tl.constexpr, BLOCK: tl.constexpr, DT: tl.constexpr):
    """Program ``pid``'s camera ``c`` and lanes: index ``r``, pixel ``(x, y)``, whether it is in the image, its centre."""
    c = pid // (TX * TY)
    t = pid % (TX * TY)
    r = tl.arange(0, BLOCK)
    x = (t % TX) * TILE + r % TILE
    y = (t // TX) * TILE + r // TILE
    inimg = (r < TILE * TILE) & (x < W) & (y < H)
    return c, r, x, y, inimg, x.to(DT) + 0.5, y.to(DT) + 0.5


@triton.jit
def _in_box(box, s, x, y):
    b = box + s * 4
    return (x >= tl.load(b)) & (x <= tl.load(b + 1)) & (y >= tl.load(b + 2)) & (y <= tl.load(b + 3))


@triton.jit
def forward_kernel(tab, box, off, ids, prm, bg, rgb, nrm, tf_, alpha_, wz_, depth_, med_, dist_, m1_, m2_, mref_,
                   last_, medi_, H, W, TX, TY, near, HAS_BG: tl.constexpr, TILE: tl.constexpr,
                   BLOCK: tl.constexpr, DT: tl.constexpr, NCOL: tl.constexpr, MIN_ALPHA_: tl.constexpr,
                   MAX_ALPHA_: tl.constexpr, MIN_T_: tl.constexpr):
    pid = tl.program_id(0)
    c, r, x, y, inimg, px, py = _tile_lanes(pid, TX, TY, W, H, TILE, BLOCK, DT)
    zero = tl.zeros([BLOCK], DT)
    mc0, mc1, mc2, lp = tl.load(prm), tl.load(prm + 1), tl.load(prm + 2), tl.load(prm + 3)
    T = zero + 1.0
    f0, f1, f2, n0, n1, n2 = zero, zero, zero, zero, zero, zero
    ws, wz, m1, m2, dist, mref, med = zero, zero, zero, zero, zero, zero, zero
    last = tl.full([BLOCK], -1, tl.int32)
    medi = tl.full([BLOCK], -1, tl.int32)
    live = inimg
    j0 = tl.load(off + pid)
    end = tl.load(off + pid + 1)
    nlive = tl.sum(live.to(tl.int32), 0)
    while (j0 < end) & (nlive > 0):  # batches of BATCH pairs: the live count (a block reduction) once a batch
        for b in range(BATCH):
            j = j0 + b
            s = tl.load(ids + j, mask=j < end, other=0)
            _, _, _, _, _, z, _, alpha, _, _, ok, _, _ = _hit(tab, s, px, py, lp, near, NCOL, MAX_ALPHA_, MIN_ALPHA_)
            # (the pair's validity as a lane vector: Triton's interpreter mistypes a scalar-bool & vector-bool)
            ok = ok & live & ((r * 0 + j) < end) & _in_box(box, s, x, y)
            nxt = T * (1.0 - alpha)
            stop = ok & (nxt < MIN_T_)
            use = ok & (nxt >= MIN_T_)
            w = tl.where(use, alpha * T, 0.0)
            zz = tl.where(use, z, 1.0)
            m_abs = mc0 + mc1 * zz + mc2 / zz
            mr = tl.where(use & (last < 0), m_abs, mref)
            m = m_abs - mr
            dist += (m * m * (1.0 - T) + m2 - 2.0 * m * m1) * w
            wz += zz * w
            ws += w
            m1 += m * w
            m2 += m * m * w
            mref = mr
            median = use & (T > 0.5)
            med = tl.where(median, z, med)
            jj = j.to(tl.int32)
            medi = tl.where(median, jj, medi)
            row = tab + s * NCOL
            f0 += w * tl.load(row + 15)
            f1 += w * tl.load(row + 16)
            f2 += w * tl.load(row + 17)
            n0 += w * tl.load(row + 18)
            n1 += w * tl.load(row + 19)
            n2 += w * tl.load(row + 20)
            T = tl.where(use, nxt, T)
            last = tl.where(use, jj, last)
            live = live & (stop == 0)
        j0 += BATCH
        nlive = tl.sum(live.to(tl.int32), 0)
    pix = (c * H + y) * W + x
    if HAS_BG:
        f0 += T * tl.load(bg)
        f1 += T * tl.load(bg + 1)
        f2 += T * tl.load(bg + 2)
    tl.store(rgb + 3 * pix, f0, mask=inimg)
    tl.store(rgb + 3 * pix + 1, f1, mask=inimg)
    tl.store(rgb + 3 * pix + 2, f2, mask=inimg)
    tl.store(nrm + 3 * pix, n0, mask=inimg)
    tl.store(nrm + 3 * pix + 1, n1, mask=inimg)
    tl.store(nrm + 3 * pix + 2, n2, mask=inimg)
    tl.store(tf_ + pix, T, mask=inimg)
    tl.store(alpha_ + pix, ws, mask=inimg)
    tl.store(wz_ + pix, wz, mask=inimg)
    tl.store(depth_ + pix, tl.where(ws > 0, wz / tl.maximum(ws, 1e-30), 0.0), mask=inimg)
    tl.store(med_ + pix, med, mask=inimg)
    tl.store(dist_ + pix, dist, mask=inimg)
    tl.store(m1_ + pix, m1, mask=inimg)
    tl.store(m2_ + pix, m2, mask=inimg)
    tl.store(mref_ + pix, mref, mask=inimg)
    tl.store(last_ + pix, last, mask=inimg)
    tl.store(medi_ + pix, medi, mask=inimg)


@triton.jit
def _load_or_zero(ptr, idx, mask, ON: tl.constexpr, zero):
    if ON:
        return tl.load(ptr + idx, mask=mask, other=0.0)
    return zero


@triton.jit
def _tile_add(ptr, v, SEM: tl.constexpr):
    """``*ptr += sum(v)``: one block-wide reduction (shared memory and barriers across the program's warps)."""
    tl.atomic_add(ptr, tl.sum(v, 0), sem=SEM)


@triton.jit
def _warp_add(ptr, v, live, NW: tl.constexpr):
    """``*ptr += sum(v)`` as ``NW`` partial sums, one a warp (lanes ``32 w .. 32 w + 31``: shuffles only, no barrier),
    each added atomically by its warp's first lane where ``live`` (``[NW, 32]``: that lane, of a warp with a lane that
    composited the pair). The adds stay in the reduction's ``[NW, 32]`` layout (a ``[NW]`` vector would be moved
    through shared memory, a barrier each)."""
    part = tl.broadcast_to(tl.sum(tl.reshape(v, [NW, 32]), 1)[:, None], [NW, 32])
    tl.atomic_add(ptr + tl.zeros([NW, 32], tl.int32), part, mask=live, sem="relaxed")


@triton.jit
def _j4(a, b, c, d):
    return tl.join(tl.join(a, b), tl.join(c, d))


@triton.jit
def _row_add(out, v0, v1, v2, v3, v4, v5, v6, v7, v8, v9, v10, v11, v12, v13, v14, v15, v16, v17, v18, v19, v20,
             zero, BLOCK: tl.constexpr):
    """``out[k] += sum(v_k)`` for the 21 columns with one block-wide reduction of a ``[BLOCK, 32]`` stack (built by
    ``tl.join``, which keeps the values in each thread's registers). The join tree puts value ``k`` at column
    ``bitreverse5(k)``; columns 21-31 hold zeros; a column that sums to zero is not added."""
    lo = tl.join(_j4(v0, v1, v2, v3), _j4(v4, v5, v6, v7))
    hi = tl.join(_j4(v8, v9, v10, v11), _j4(v12, v13, v14, v15))
    top = tl.join(_j4(v16, v17, v18, v19), _j4(v20, zero, zero, zero))
    nil = tl.join(_j4(zero, zero, zero, zero), _j4(zero, zero, zero, zero))
    stack = tl.reshape(tl.join(tl.join(lo, hi), tl.join(top, nil)), [BLOCK, 32])
    tot = tl.sum(stack, 0)
    col = tl.arange(0, 32)
    k = ((col & 1) << 4) | ((col & 2) << 2) | (col & 4) | ((col & 8) >> 2) | ((col & 16) >> 4)
    tl.atomic_add(out + k, tot, mask=(k < 21) & (tot != 0), sem="relaxed")


@triton.jit
def _add(ptr, v, live, REDUCE: tl.constexpr, NW: tl.constexpr):
    """One column's ``*ptr += sum(v)`` as ``triton2d.BACKWARD_SUM`` says (``REDUCE``: 0 "tile_acq", 1 "tile", 2
    "warp"; 3, "row", sums by warp where a pair has only its three colour columns)."""
    if REDUCE == 0:
        _tile_add(ptr, v, "acq_rel")
    elif REDUCE == 1:
        _tile_add(ptr, v, "relaxed")
    else:
        _warp_add(ptr, v, live, NW)


@triton.jit
def _pair(tab, grad, s, j, ok, u, v, ip, dx, dy, z, g, alpha, op, use3d, tz0, tz1, px, py, lp, tr, sa, go0, go1, go2,
          gn0, gn1, gn2, ga, gd, gm, gdis, mc0, mc1, mc2, mref, m1, m2, Wt, medi, zero, GEO: tl.constexpr,
          REDUCE: tl.constexpr, NW: tl.constexpr, BLOCK: tl.constexpr, NCOL: tl.constexpr, MAX_ALPHA_: tl.constexpr):
    """One pair of the backward (entry ``s``, list position ``j``): its 21 gradient columns added to ``grad[s]``;
    returns the lanes' transmittance in front of it and the running sum of ``w * dL/dw`` behind it."""
    live = ok
    if REDUCE >= 2:  # [NW, 32]: each warp's first lane, where a lane of the warp composited the pair ("row" sums
        # the three colour columns of a frozen geometry this way)
        anyw = tl.max(tl.reshape(ok.to(tl.int32), [NW, 32]), 1)[:, None] > 0
        live = anyw & (tl.arange(0, 32)[None, :] == 0)
    inv = 1.0 / (1.0 - alpha)
    Ti = tr * inv
    w = tl.where(ok, alpha * Ti, 0.0)
    tr = tl.where(ok, Ti, tr)
    row = tab + s * NCOL
    out = grad + s * NCOL
    c15, c16, c17 = w * go0, w * go1, w * go2
    if GEO:
        zz = tl.where(ok, z, 1.0)
        iz = 1.0 / zz
        m = mc0 + mc1 * zz + mc2 * iz - mref
        dm_dz = mc1 - mc2 * iz * iz
        gw = ga + gd * zz + gdis * (m * m * Wt - 2.0 * m * m1 + m2)
        gw += go0 * tl.load(row + 15) + go1 * tl.load(row + 16) + go2 * tl.load(row + 17)
        gw += gn0 * tl.load(row + 18) + gn1 * tl.load(row + 19) + gn2 * tl.load(row + 20)
        gz = w * gd + gdis * 2.0 * w * (m * Wt - m1) * dm_dz + tl.where(ok & (medi == j), gm, 0.0)
        dalpha = gw * Ti - sa * inv
        sa += gw * w
        gok = ok & (op * g <= MAX_ALPHA_)  # a clamped alpha has no gradient
        dpow = tl.where(gok, dalpha * op * g, 0.0)
        h3 = ok & use3d
        h2 = ok & (use3d == 0)
        gu = tl.where(h3, -dpow * u + gz * tz0, 0.0)
        gv = tl.where(h3, -dpow * v + gz * tz1, 0.0)
        gp0 = gu * ip
        gp1 = gv * ip
        gp2 = -(gu * u + gv * v) * ip
        c0, c1, c2, c3, c4, c5 = px * gp0, px * gp1, px * gp2, py * gp0, py * gp1, py * gp2
        c9 = tl.where(h2, -dpow * lp * dx, 0.0)
        c10 = tl.where(h2, -dpow * lp * dy, 0.0)
        c11 = tl.where(gok, dalpha * g, 0.0)
        c12 = tl.where(h3, gz * u, 0.0)
        c13 = tl.where(h3, gz * v, 0.0)
        c14 = tl.where(ok, gz, 0.0)
        c18, c19, c20 = w * gn0, w * gn1, w * gn2
        if REDUCE == 3:
            _row_add(out, c0, c1, c2, c3, c4, c5, gp0, gp1, gp2, c9, c10, c11, c12, c13, c14, c15, c16, c17,
                     c18, c19, c20, zero, BLOCK)
        else:
            _add(out + 0, c0, live, REDUCE, NW)
            _add(out + 1, c1, live, REDUCE, NW)
            _add(out + 2, c2, live, REDUCE, NW)
            _add(out + 3, c3, live, REDUCE, NW)
            _add(out + 4, c4, live, REDUCE, NW)
            _add(out + 5, c5, live, REDUCE, NW)
            _add(out + 6, gp0, live, REDUCE, NW)
            _add(out + 7, gp1, live, REDUCE, NW)
            _add(out + 8, gp2, live, REDUCE, NW)
            _add(out + 9, c9, live, REDUCE, NW)
            _add(out + 10, c10, live, REDUCE, NW)
            _add(out + 11, c11, live, REDUCE, NW)
            _add(out + 12, c12, live, REDUCE, NW)
            _add(out + 13, c13, live, REDUCE, NW)
            _add(out + 14, c14, live, REDUCE, NW)
            _add(out + 15, c15, live, REDUCE, NW)
            _add(out + 16, c16, live, REDUCE, NW)
            _add(out + 17, c17, live, REDUCE, NW)
            _add(out + 18, c18, live, REDUCE, NW)
            _add(out + 19, c19, live, REDUCE, NW)
            _add(out + 20, c20, live, REDUCE, NW)
    else:
        _add(out + 15, c15, live, REDUCE, NW)
        _add(out + 16, c16, live, REDUCE, NW)
        _add(out + 17, c17, live, REDUCE, NW)
    return tr, sa


@triton.jit
def backward_kernel(tab, box, off, ids, prm, bg, tf_, alpha_, wz_, m1_, m2_, mref_, last_, medi_, g_rgb, g_nrm,
                    g_alpha, g_depth, g_med, g_dist, grad, H, W, TX, TY, near, HAS_BG: tl.constexpr,
                    G_RGB: tl.constexpr, G_NRM: tl.constexpr, G_ALPHA: tl.constexpr, G_DEPTH: tl.constexpr,
                    G_MED: tl.constexpr, G_DIST: tl.constexpr, GEO: tl.constexpr, TILE: tl.constexpr,
                    BLOCK: tl.constexpr, DT: tl.constexpr, NCOL: tl.constexpr, MAX_ALPHA_: tl.constexpr,
                    MIN_ALPHA_: tl.constexpr, REDUCE: tl.constexpr, NW: tl.constexpr):
    pid = tl.program_id(0)
    c, _, x, y, inimg, px, py = _tile_lanes(pid, TX, TY, W, H, TILE, BLOCK, DT)
    pix = (c * H + y) * W + x
    zero = tl.zeros([BLOCK], DT)
    mc0, mc1, mc2, lp = tl.load(prm), tl.load(prm + 1), tl.load(prm + 2), tl.load(prm + 3)
    # the composited sums' gradients: rgb = sum w c + (1 - alpha) bg, depth = sum w z / alpha
    go0 = _load_or_zero(g_rgb, 3 * pix, inimg, G_RGB, zero)
    go1 = _load_or_zero(g_rgb, 3 * pix + 1, inimg, G_RGB, zero)
    go2 = _load_or_zero(g_rgb, 3 * pix + 2, inimg, G_RGB, zero)
    gn0 = _load_or_zero(g_nrm, 3 * pix, inimg, G_NRM, zero)
    gn1 = _load_or_zero(g_nrm, 3 * pix + 1, inimg, G_NRM, zero)
    gn2 = _load_or_zero(g_nrm, 3 * pix + 2, inimg, G_NRM, zero)
    ga = _load_or_zero(g_alpha, pix, inimg, G_ALPHA, zero)
    if HAS_BG:
        ga -= go0 * tl.load(bg) + go1 * tl.load(bg + 1) + go2 * tl.load(bg + 2)
    a = tl.load(alpha_ + pix, mask=inimg, other=0.0)
    gd = zero
    if G_DEPTH:
        gdep = tl.load(g_depth + pix, mask=inimg, other=0.0)
        ac = tl.maximum(a, 1e-30)
        gd = tl.where(a > 0, gdep / ac, 0.0)
        ga -= tl.where(a >= 1e-30, gdep * tl.load(wz_ + pix, mask=inimg, other=0.0) / ac / ac, 0.0)
    gm = _load_or_zero(g_med, pix, inimg, G_MED, zero)
    gdis = _load_or_zero(g_dist, pix, inimg, G_DIST, zero)
    tf = tl.load(tf_ + pix, mask=inimg, other=1.0)
    m1 = tl.load(m1_ + pix, mask=inimg, other=0.0)
    m2 = tl.load(m2_ + pix, mask=inimg, other=0.0)
    mref = tl.load(mref_ + pix, mask=inimg, other=0.0)
    last = tl.load(last_ + pix, mask=inimg, other=-1)
    medi = tl.load(medi_ + pix, mask=inimg, other=-1)
    Wt = 1.0 - tf
    tr = tf
    sa = zero
    jmax = tl.max(last, 0)
    start = tl.load(off + pid).to(tl.int32)
    for k in range(jmax - start + 1):
        j = jmax - k
        s = tl.load(ids + j)
        u, v, ip, dx, dy, z, g, alpha, op, use3d, ok, tz0, tz1 = _hit(tab, s, px, py, lp, near, NCOL, MAX_ALPHA_,
                                                                      MIN_ALPHA_)
        ok = ok & (j <= last) & _in_box(box, s, x, y)
        if REDUCE < 2:  # the block reductions skip a pair no pixel of the tile composited (a reduction too)
            if tl.max(ok.to(tl.int32), 0) > 0:
                tr, sa = _pair(tab, grad, s, j, ok, u, v, ip, dx, dy, z, g, alpha, op, use3d, tz0, tz1, px, py, lp, tr,
                               sa, go0, go1, go2, gn0, gn1, gn2, ga, gd, gm, gdis, mc0, mc1, mc2, mref, m1, m2, Wt,
                               medi, zero, GEO, REDUCE, NW, BLOCK, NCOL, MAX_ALPHA_)
        else:  # every pair computed; one no pixel composited adds nothing
            tr, sa = _pair(tab, grad, s, j, ok, u, v, ip, dx, dy, z, g, alpha, op, use3d, tz0, tz1, px, py, lp, tr,
                           sa, go0, go1, go2, gn0, gn1, gn2, ga, gd, gm, gdis, mc0, mc1, mc2, mref, m1, m2, Wt,
                           medi, zero, GEO, REDUCE, NW, BLOCK, NCOL, MAX_ALPHA_)
