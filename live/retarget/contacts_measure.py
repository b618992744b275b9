"""The gaps of hands and forearms to the body in one pose, compiled (numba): the loops behind
``contacts_surface.measure`` (which documents what they compute) and ``SurfaceModel.sample``.

Written with numpy arrays, a measure is some sixty array calls on a few hundred probes, and a
frame measures two to five times: the calls' overhead, not the arithmetic, would set the retarget
stage's p95 (300 against 45 us a measure). Here one pass over the probes does the same
arithmetic. The kernels compile on their first call in a process (numba caches the machine code
on disk: a few seconds once per machine, then a fraction of a second);
``contacts_surface.warm_up`` makes that call, and the pipeline's retarget stage makes it when it
starts.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Softmin entries more than this many tau above their group's least raw distance weigh less
#: than e^-12: they get no skinning correction.
LOOK_TAUS = 12.0


@njit(cache=True, nogil=True, inline="always")
def _sample(data, nearest, lo, top, strides, base, part, x, y, z, inv_cell, cell, out):
    """Trilinear signed distance and gradient of part's grid at a local point (x, y, z, rest
    units) into out (4,), continued past the grid's edge by the distance to it; returns the skin
    vertex nearest the closest point of the grid node nearest the point."""
    gx, gy, gz = (x - lo[part, 0]) * inv_cell, (y - lo[part, 1]) * inv_cell, (z - lo[part, 2]) * inv_cell
    cx, cy, cz = min(max(gx, 0.0), top[part, 0]), min(max(gy, 0.0), top[part, 1]), min(max(gz, 0.0), top[part, 2])
    ix, iy, iz = math.floor(cx), math.floor(cy), math.floor(cz)
    fx, fy, fz = cx - ix, cy - iy, cz - iz
    sx, sy, sz = strides[part, 0], strides[part, 1], strides[part, 2]
    row = base[part] + int(ix * sx + iy * sy + iz * sz)
    isx, isy, isz = int(sx), int(sy), int(sz)
    w00, w01, w10, w11 = (1 - fx) * (1 - fy), (1 - fx) * fy, fx * (1 - fy), fx * fy
    for v in range(4):
        out[v] = ((w00 * data[row, v] + w01 * data[row + isy, v] + w10 * data[row + isx, v]
                   + w11 * data[row + isx + isy, v]) * (1 - fz)
                  + (w00 * data[row + isz, v] + w01 * data[row + isy + isz, v] + w10 * data[row + isx + isz, v]
                     + w11 * data[row + isx + isy + isz, v]) * fz)
    bx, by, bz = gx - cx, gy - cy, gz - cz
    out[0] += math.sqrt(bx * bx + by * by + bz * bz) * cell
    return nearest[base[part] + int(np.rint(cx) * sx + np.rint(cy) * sy + np.rint(cz) * sz)]


@njit(cache=True, nogil=True)
def sample_points(data, nearest, lo, top, strides, base, cell, parts, local):
    """``_sample`` of parts[q] at local[q] (Q, 3): (Q, 4) distances and gradients, (Q,) vertices."""
    out = np.empty((len(parts), 4))
    vertex = np.empty(len(parts), np.int64)
    inv_cell = 1.0 / cell
    for q in range(len(parts)):
        vertex[q] = _sample(data, nearest, lo, top, strides, base, parts[q], local[q, 0], local[q, 1], local[q, 2],
                            inv_cell, cell, out[q])
    return out, vertex


@njit(cache=True, nogil=True, inline="always")
def _skin(v, transforms, vertices, skin_joints, skin_weights, i):
    """Coordinate i of skin vertex v by linear blend skinning (transforms (22, 12): [A | b])."""
    x, y, z = vertices[v, 0], vertices[v, 1], vertices[v, 2]
    acc = 0.0
    for c in range(skin_joints.shape[1]):
        t = transforms[skin_joints[v, c]]
        acc += skin_weights[v, c] * (t[3 * i] * x + t[3 * i + 1] * y + t[3 * i + 2] * z + t[9 + i])
    return acc


@njit(cache=True, nogil=True, inline="always")
def _skinned(v, transforms, vertices, skin_joints, skin_weights, skinned, ready):
    """Skin vertex v once per measure (``skinned`` / ``ready``: what this measure has skinned)."""
    if not ready[v]:
        for i in range(3):
            skinned[v, i] = _skin(v, transforms, vertices, skin_joints, skin_weights, i)
        ready[v] = True


@njit(cache=True, nogil=True)
def _walk(v, region, p, steps, reach, transforms, vertices, normals, skin_joints, skin_weights, ring_start, ring,
          vertex_region, skinned, ready, direction):
    """Signed distance of point p to the skinned skin of ``region``, from vertex v on: along the
    mesh's edges to the region's skinned vertex nearest p (at most ``steps`` moves), then p's
    offset along that vertex's skinned normal (into ``direction``); NaN (``direction`` left
    alone) when that vertex is farther than ``reach`` from p. Where a vertex of another
    region lies nearer still, p is beyond this region's edge: outside, at its distance from the
    vertex (as a closest point on a part's open edge counts)."""
    _skinned(v, transforms, vertices, skin_joints, skin_weights, skinned, ready)
    best = (skinned[v, 0] - p[0]) ** 2 + (skinned[v, 1] - p[1]) ** 2 + (skinned[v, 2] - p[2]) ** 2
    beyond = False
    for _ in range(steps):
        nxt = -1
        beyond = False
        for r in range(ring_start[v], ring_start[v + 1]):
            w = ring[r]
            _skinned(w, transforms, vertices, skin_joints, skin_weights, skinned, ready)
            d = (skinned[w, 0] - p[0]) ** 2 + (skinned[w, 1] - p[1]) ** 2 + (skinned[w, 2] - p[2]) ** 2
            if d < best:
                if vertex_region[w] == region:
                    best, nxt = d, w
                else:
                    beyond = True
        if nxt < 0:
            break
        v = nxt
    if best > reach * reach:
        return np.nan  # the walk stopped on skin no nearer than this: a local minimum far off
    # The skinned normal: the blended transform's linear part applied to the rest normal.
    n = np.zeros(3)
    for c in range(skin_joints.shape[1]):
        t = transforms[skin_joints[v, c]]
        wt = skin_weights[v, c]
        for i in range(3):
            n[i] += wt * (t[3 * i] * normals[v, 0] + t[3 * i + 1] * normals[v, 1] + t[3 * i + 2] * normals[v, 2])
    norm = max(math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), 1e-12)
    offset = 0.0
    for i in range(3):
        direction[i] = n[i] / norm
        offset += direction[i] * (p[i] - skinned[v, i])
    if beyond and offset < 0.0:
        far = max(math.sqrt(best), 1e-12)
        for i in range(3):
            direction[i] = (p[i] - skinned[v, i]) / far
        return far
    # The skin about the vertex as a disc as wide as its edges are long: a point to the side of
    # it (at a fold, past the skin's edge) is as far as the disc's rim, not the plane.
    edge = 0.0
    for r in range(ring_start[v], ring_start[v + 1]):
        w = ring[r]
        edge += math.sqrt((skinned[w, 0] - skinned[v, 0]) ** 2 + (skinned[w, 1] - skinned[v, 1]) ** 2
                          + (skinned[w, 2] - skinned[v, 2]) ** 2)
    edge /= max(ring_start[v + 1] - ring_start[v], 1)
    side = max(math.sqrt(max(best - offset * offset, 0.0)) - edge, 0.0)
    if side == 0.0:
        return offset
    return math.copysign(math.sqrt(offset * offset + side * side), offset)


@njit(cache=True, nogil=True)
def probe_gaps(glob, pos, scale, probes, reach, band, skin_slack, tau,
                 probe_vertices, probe_joint, probe_centre, probe_radius, allowed,
                 frames, part_centre_rest, part_radius, box_centre, box_half,
                 data, nearest, lo, top, strides, base, cell, vertex_region,
                 vertices, rest_joints, skin_joints, skin_weights, normals, ring_start, ring, walk_steps, walk_from,
                 walk_reach, part_region):
    """Gaps of probe sets ``probes`` (indices into PROBES; reach and band per probe set) to the
    regions they are tested against, grouped by (probe set, region) in that order: probe (G,),
    region (G,), gap (G,), direction (G, 3), point (G, 3). Empty when nothing is near."""
    n_slots, count = len(probes), probe_vertices.shape[1]
    n_parts, n_regions = len(frames), int(part_region.max()) + 1  # every region has a part
    # Each part's bounding sphere in the pose.
    part_centre = np.empty((n_parts, 3))
    for k in range(n_parts):
        f = frames[k]
        for i in range(3):
            part_centre[k, i] = pos[f, i] + scale * (glob[f, i, 0] * part_centre_rest[k, 0]
                                                     + glob[f, i, 1] * part_centre_rest[k, 1]
                                                     + glob[f, i, 2] * part_centre_rest[k, 2])
    # First without skinning: each probe set's sphere carried rigidly by its joint, grown by
    # skin_slack for what skinning moves it by; a frame with nothing near ends here.
    anything = False
    for s in range(n_slots):
        probe, j = probes[s], probe_joint[probes[s]]
        c = np.empty(3)
        for i in range(3):
            c[i] = pos[j, i] + scale * (glob[j, i, 0] * probe_centre[probe, 0] + glob[j, i, 1] * probe_centre[probe, 1]
                                        + glob[j, i, 2] * probe_centre[probe, 2])
        for k in range(n_parts):
            if allowed[probe, k]:
                d = math.sqrt((c[0] - part_centre[k, 0]) ** 2 + (c[1] - part_centre[k, 1]) ** 2
                              + (c[2] - part_centre[k, 2]) ** 2)
                if d - (probe_radius[probe] * scale + skin_slack) - part_radius[k] * scale < reach[s]:
                    anything = True
    none = np.zeros(0, np.int64)
    if not anything:
        return none, none, np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
    # live.body.skinning.pose_transforms of (scale G, p), here rather than passed in: only past
    # the early exit above (a call from numpy costs 4 us of the measure's 38).
    transforms = np.empty((len(glob), 12))
    for j in range(len(glob)):
        for i in range(3):
            for c3 in range(3):
                transforms[j, 3 * i + c3] = glob[j, i, c3] * scale
            transforms[j, 9 + i] = pos[j, i] - (transforms[j, 3 * i] * rest_joints[j, 0]
                                                + transforms[j, 3 * i + 1] * rest_joints[j, 1]
                                                + transforms[j, 3 * i + 2] * rest_joints[j, 2])
    # The probes skinned like the mesh, and each set's bounding sphere; the pairs near enough.
    pts = np.empty((n_slots, count, 3))
    which = np.empty(n_slots * n_parts, np.int64)
    parts = np.empty(n_slots * n_parts, np.int64)
    pairs = 0
    for s in range(n_slots):
        probe = probes[s]
        c = np.zeros(3)
        for n in range(count):
            for i in range(3):
                pts[s, n, i] = _skin(probe_vertices[probe, n], transforms, vertices, skin_joints, skin_weights, i)
                c[i] += pts[s, n, i]
        c /= count
        radius = 0.0
        for n in range(count):
            radius = max(radius, (pts[s, n, 0] - c[0]) ** 2 + (pts[s, n, 1] - c[1]) ** 2 + (pts[s, n, 2] - c[2]) ** 2)
        radius = math.sqrt(radius)
        for k in range(n_parts):
            d = math.sqrt((c[0] - part_centre[k, 0]) ** 2 + (c[1] - part_centre[k, 1]) ** 2
                          + (c[2] - part_centre[k, 2]) ** 2)
            if allowed[probe, k] and d - radius - part_radius[k] * scale < reach[s]:
                which[pairs], parts[pairs] = s, k
                pairs += 1
    # Every probe of every near pair within the band of the part's skin box, sampled in its grid.
    cap = pairs * count
    e_group = np.empty(cap, np.int64)
    e_vertex = np.empty(cap, np.int64)
    e_frame = np.empty(cap, np.int64)
    e_dist = np.empty(cap)
    e_dir = np.empty((cap, 3))
    e_pt = np.empty((cap, 3))
    low = np.full(n_slots * n_regions, np.inf)
    inv_scale, inv_cell = 1.0 / scale, 1.0 / cell
    out = np.empty(4)
    used = 0
    for p in range(pairs):
        s, k = which[p], parts[p]
        f = frames[k]
        for n in range(count):
            dx, dy, dz = pts[s, n, 0] - pos[f, 0], pts[s, n, 1] - pos[f, 1], pts[s, n, 2] - pos[f, 2]
            # R^T (p - t) in the model's rest units.
            x = (dx * glob[f, 0, 0] + dy * glob[f, 1, 0] + dz * glob[f, 2, 0]) * inv_scale
            y = (dx * glob[f, 0, 1] + dy * glob[f, 1, 1] + dz * glob[f, 2, 1]) * inv_scale
            z = (dx * glob[f, 0, 2] + dy * glob[f, 1, 2] + dz * glob[f, 2, 2]) * inv_scale
            worst = max(abs(x - box_centre[k, 0]) - box_half[k, 0], abs(y - box_centre[k, 1]) - box_half[k, 1],
                        abs(z - box_centre[k, 2]) - box_half[k, 2])
            if not worst < band[s]:
                continue
            vertex = _sample(data, nearest, lo, top, strides, base, k, x, y, z, inv_cell, cell, out)
            region = part_region[k]  # a part allowed for a probe set is of a region allowed for it
            gx = glob[f, 0, 0] * out[1] + glob[f, 0, 1] * out[2] + glob[f, 0, 2] * out[3]
            gy = glob[f, 1, 0] * out[1] + glob[f, 1, 1] * out[2] + glob[f, 1, 2] * out[3]
            gz = glob[f, 2, 0] * out[1] + glob[f, 2, 1] * out[2] + glob[f, 2, 2] * out[3]
            norm = max(math.sqrt(gx * gx + gy * gy + gz * gz), 1e-9)
            group = s * n_regions + region
            e_group[used], e_vertex[used], e_frame[used], e_dist[used] = group, vertex, f, out[0] * scale
            e_dir[used, 0], e_dir[used, 1], e_dir[used, 2] = gx / norm, gy / norm, gz / norm
            e_pt[used, 0], e_pt[used, 1], e_pt[used, 2] = pts[s, n, 0], pts[s, n, 1], pts[s, n, 2]
            low[group] = min(low[group], e_dist[used])
            used += 1
    # Where the softmin will look, the rigid part's distance corrected by how far skinning puts
    # the nearest vertex from where the part moved rigidly would (a bent spine's belly); where
    # that is more than walk_from, the rigid grid named the wrong skin: the distance is taken on
    # the skinned mesh itself instead (``_walk``).
    gap = np.full(n_slots * n_regions, np.inf)
    skinned = np.empty((len(vertices), 3))
    ready = np.zeros(len(vertices), np.bool_)
    for e in range(used):
        g = e_group[e]
        if e_dist[e] < low[g] + LOOK_TAUS * tau:
            v, f = e_vertex[e], e_frame[e]
            rx = (vertices[v, 0] - rest_joints[f, 0]) * scale
            ry = (vertices[v, 1] - rest_joints[f, 1]) * scale
            rz = (vertices[v, 2] - rest_joints[f, 2]) * scale
            _skinned(v, transforms, vertices, skin_joints, skin_weights, skinned, ready)
            moved = 0.0
            shift = 0.0
            for i in range(3):
                d = skinned[v, i] - (glob[f, i, 0] * rx + glob[f, i, 1] * ry + glob[f, i, 2] * rz + pos[f, i])
                moved += e_dir[e, i] * d
                shift += d * d
            walked = np.nan
            if shift > walk_from * walk_from:
                walked = _walk(v, g % n_regions, e_pt[e], walk_steps, walk_reach, transforms, vertices, normals,
                               skin_joints, skin_weights, ring_start, ring, vertex_region, skinned, ready, e_dir[e])
            if np.isnan(walked):
                e_dist[e] -= moved
            else:
                e_dist[e] = walked
        gap[g] = min(gap[g], e_dist[e])
    # The gap: the nearest probe's distance; direction and point softmin-weighted.
    total = np.zeros(n_slots * n_regions)
    direction = np.zeros((n_slots * n_regions, 3))
    point = np.zeros((n_slots * n_regions, 3))
    for e in range(used):
        g = e_group[e]
        w = math.exp(-(e_dist[e] - gap[g]) / tau)
        total[g] += w
        for i in range(3):
            direction[g, i] += w * e_dir[e, i]
            point[g, i] += w * e_pt[e, i]
    rows = np.flatnonzero(total > 0.0)
    out_probe, out_region = np.empty(len(rows), np.int64), np.empty(len(rows), np.int64)
    for r in range(len(rows)):
        g = rows[r]
        out_probe[r], out_region[r] = probes[g // n_regions], g % n_regions
        norm = max(math.sqrt(direction[g, 0] ** 2 + direction[g, 1] ** 2 + direction[g, 2] ** 2), 1e-9)
        for i in range(3):
            direction[g, i] /= norm
            point[g, i] /= total[g]
    return out_probe, out_region, gap[rows], direction[rows], point[rows]
