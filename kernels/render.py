"""Rasteriser for one world of a batch: agents splat into per-pixel buffers, then one pass composes RGB.

Two kernels per frame, no per-agent Python:
1. `splat_agents`, one thread per agent slot of the rendered world. Each live agent visits the pixels
   of its bounding box (wrapped around the torus) and
   - writes `slot + 1` into `body_key` with `atomic_max` where its fish/shark shape covers any of the
     pixel's 2 x 2 sub-samples: the highest slot wins, whatever the thread order, so overlaps are
     deterministic (predators, whose slots follow the prey's, lie on top);
   - with view cones, adds 1 to `cone_count[type]` where the pixel lies in its view sector (a count
     blends order-independently: alpha_n = 1 - (1 - alpha)^n);
   - with hit boxes / velocities, sets bits of `overlay` with `atomic_or` (same result in any order).
2. `compose_image`, one thread per pixel, bottom to top: background, cone tint, velocity arrows (so
   they leave the body at the nose), the winning agent's shape (its parts recomputed from its slot, so
   the splat needs no colour buffer; sub-samples outside the shape show the layers beneath, not an
   agent beneath: a faint seam where agents overlap), hit-box rings.

Pixel (row i, column j) has its centre at world ((j + 0.5) * pixel_width, (i + 0.5) * pixel_height):
x right, y down, row 0 at the top. Each pixel test uses the torus-shortest displacement from the agent
to the pixel centre, so an agent near an edge also appears across the seam. Shapes are anti-aliased
with 2 x 2 sub-samples per pixel. An agent whose radius is under `DOT_RADIUS_PX` image pixels is drawn
as the one pixel under its centre, so a zoomed-out world of a million agents shows every agent, cheaply.
"""

import warp as wp

from .common import PREDATOR, PREY, WorldParams, current, torus_delta
from .state import Agents

wp.set_module_options({"enable_backward": False})

# Shape parts, as returned by `shape_part` (0: the pixel is outside the shape).
PART_NONE = wp.constant(0)
PART_BODY = wp.constant(1)
PART_FIN = wp.constant(2)
PART_EYE = wp.constant(3)
PART_OUTLINE = wp.constant(4)
PART_STRIPE = wp.constant(5)  # dorsal marking

# Bits of the overlay buffer.
BIT_HIT_BOX_PREDATOR = wp.constant(1)
BIT_HIT_BOX_PREY = wp.constant(2)
BIT_VELOCITY = wp.constant(4)
BIT_FLOW = wp.constant(8)

# A shape whose radius is under this many image pixels is drawn as one pixel (its details would not show).
DOT_RADIUS_PX = wp.constant(0.75)
# Under this radius in image pixels a shape is drawn as a plain oval along the heading (fins and eyes
# would be sub-pixel), which keeps crowded zoomed-out frames cheap.
DETAIL_RADIUS_PX = wp.constant(3.0)


@wp.struct
class RenderParams:
    """Geometry and options of one frame. Per-type vectors are indexed by type code (PREDATOR, PREY)."""

    world_width: float  # px (world units)
    world_height: float
    width_px: int  # image columns
    height_px: int  # image rows
    pixel_width: float  # world px per image column
    pixel_height: float  # world px per image row
    world: int  # index of the rendered world in the batch
    prey_capacity: int  # slots [0, prey_capacity) are prey
    radius: wp.vec2  # hit-box radius per type, px
    cone_radius: wp.vec2  # view distance per type, clipped to the world's half diagonal, px
    cos_half_fov: wp.vec2  # cos(fov / 2) per type; -2 for a full circle
    outline: float  # outline thickness, world px
    ring: float  # half thickness of hit-box rings, world px
    line_px: float  # half thickness of velocity lines, image pixels
    velocity_scale: float  # velocity arrows are velocity * velocity_scale long (steps), px
    view_cones: int  # 1: draw view cones
    hit_boxes: int  # 1: draw hit boxes
    velocities: int  # 1: draw velocity arrows
    flow_spacing: int  # image pixels between the flow arrows' grid points


@wp.struct
class Palette:
    """RGB colours, 0..255 floats."""

    background: wp.vec3
    prey_body: wp.vec3
    prey_fin: wp.vec3
    prey_outline: wp.vec3
    prey_eye: wp.vec3
    prey_stripe: wp.vec3
    predator_body: wp.vec3
    predator_fin: wp.vec3
    predator_outline: wp.vec3
    predator_eye: wp.vec3
    predator_stripe: wp.vec3
    prey_cone: wp.vec3
    predator_cone: wp.vec3
    cone_alpha: wp.vec2  # opacity of one cone per type (PREDATOR, PREY)
    prey_hit_box: wp.vec3
    predator_hit_box: wp.vec3
    velocity: wp.vec3
    flow: wp.vec3


@wp.func
def wrap_index(k: int, n: int) -> int:
    """k modulo n in [0, n), for any sign of k."""
    m = k % n
    if m < 0:
        m = m + n
    return m


@wp.func
def first_pixel(lo: float, inv_size: float) -> int:
    """Smallest (unwrapped) pixel index whose centre (k + 0.5) * size is >= lo."""
    return int(wp.ceil(lo * inv_size - 0.5))


@wp.func
def last_pixel(hi: float, inv_size: float) -> int:
    """Largest (unwrapped) pixel index whose centre is <= hi."""
    return int(wp.floor(hi * inv_size - 0.5))


@wp.func
def pixel_offset(p: RenderParams, i: int, j: int, centre: wp.vec2) -> wp.vec2:
    """Torus-shortest displacement from `centre` to the centre of pixel (row i, column j), world px."""
    x = (float(j) + 0.5) * p.pixel_width
    y = (float(i) + 0.5) * p.pixel_height
    return wp.vec2(torus_delta(x - centre[0], p.world_width), torus_delta(y - centre[1], p.world_height))


@wp.func
def in_ellipse(u: float, v: float, cu: float, a: float, b: float) -> int:
    """1 if (u, v) lies in the ellipse centred at (cu, 0) with semi-axes a (along u) and b."""
    du = (u - cu) / a
    dv = v / b
    if du * du + dv * dv <= 1.0:
        return 1
    return 0


@wp.func
def edge_side(p: wp.vec2, a: wp.vec2, b: wp.vec2) -> float:
    return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])


@wp.func
def in_triangle(p: wp.vec2, a: wp.vec2, b: wp.vec2, c: wp.vec2) -> int:
    """1 if p lies in triangle abc (either winding)."""
    s0 = edge_side(p, a, b)
    s1 = edge_side(p, b, c)
    s2 = edge_side(p, c, a)
    if (s0 >= 0.0 and s1 >= 0.0 and s2 >= 0.0) or (s0 <= 0.0 and s1 <= 0.0 and s2 <= 0.0):
        return 1
    return 0


@wp.func
def prey_part(u: float, v: float, edge: float) -> int:
    """Fish seen from above, nose at +u: oval body, narrowing tail stalk, forked tail fin, small
    pectoral fins and two eyes. (u, v) and `edge` (outline thickness) are in units of the hit-box
    radius; the shape fits in the unit circle."""
    av = wp.abs(v)
    q = wp.vec2(u, av)
    # eyes near the nose, one each side
    du = u - 0.4
    dv = av - 0.14
    if du * du + dv * dv <= 0.07 * 0.07:
        return PART_EYE
    if in_ellipse(u, av, 0.14, 0.56, 0.3) == 1:
        if in_ellipse(u, av, 0.14, wp.max(0.56 - edge, 1e-3), wp.max(0.3 - edge, 1e-3)) == 0:
            return PART_OUTLINE
        return PART_BODY
    # tail stalk, narrowing from the body to the fin
    if in_triangle(q, wp.vec2(-0.3, 0.0), wp.vec2(-0.3, 0.17), wp.vec2(-0.66, 0.07)) == 1 or (
        u >= -0.66 and u <= -0.3 and av <= 0.07
    ):
        return PART_BODY
    # forked tail fin: a fan behind the stalk with a notch cut into its trailing edge
    if in_triangle(q, wp.vec2(-0.6, 0.0), wp.vec2(-0.95, 0.34), wp.vec2(-0.95, 0.0)) == 1:
        if in_triangle(q, wp.vec2(-0.82, 0.0), wp.vec2(-0.96, 0.14), wp.vec2(-0.96, 0.0)) == 0:
            return PART_FIN
    # pectoral fins behind the eyes, swept back
    if in_triangle(q, wp.vec2(0.18, 0.24), wp.vec2(-0.06, 0.27), wp.vec2(-0.16, 0.46)) == 1:
        return PART_FIN
    return PART_NONE


@wp.func
def predator_part(u: float, v: float, edge: float) -> int:
    """Shark seen from above, nose at +u: slim body with a pointed snout, broad swept pectoral fins,
    a crescent tail, the dorsal fin as a dark wedge on the spine, eyes on the snout.
    Units as in `prey_part`."""
    av = wp.abs(v)
    q = wp.vec2(u, av)
    du = u - 0.56
    dv = av - 0.1
    if du * du + dv * dv <= 0.035 * 0.035:
        return PART_EYE
    # body: an ellipse, narrowed ahead of u = 0.3 into a pointed snout
    half = 0.23
    if u > 0.3:
        half = 0.23 * (1.0 - 0.45 * (u - 0.3) / 0.6)
    if in_ellipse(u, av, 0.05, 0.85, half) == 1:
        if in_ellipse(u, av, 0.05, wp.max(0.85 - edge, 1e-3), wp.max(half - edge, 1e-3)) == 0:
            return PART_OUTLINE
        # dorsal fin seen from above: a narrow darker wedge on the spine
        if in_triangle(q, wp.vec2(0.18, 0.0), wp.vec2(-0.12, 0.07), wp.vec2(-0.3, 0.0)) == 1:
            return PART_STRIPE
        return PART_BODY
    # pectoral fins: broad swept-back triangles on both sides
    if in_triangle(q, wp.vec2(0.34, 0.15), wp.vec2(-0.06, 0.2), wp.vec2(-0.2, 0.6)) == 1:
        return PART_FIN
    # crescent tail: two lobes swept back from the tail stalk
    if in_triangle(q, wp.vec2(-0.6, 0.07), wp.vec2(-0.96, 0.28), wp.vec2(-0.8, 0.0)) == 1:
        return PART_FIN
    return PART_NONE


@wp.func
def shape_part(p: RenderParams, agent_type: int, d: wp.vec2, heading: wp.vec2) -> int:
    """Part of an agent's shape at displacement d (world px) from its centre, 0 if outside."""
    h = heading
    if wp.length_sq(h) < 1e-12:
        h = wp.vec2(0.0, -1.0)  # no heading recorded: point up
    r = p.radius[agent_type]
    inv_r = 1.0 / r
    u = (d[0] * h[0] + d[1] * h[1]) * inv_r
    v = (d[1] * h[0] - d[0] * h[1]) * inv_r
    if r < DETAIL_RADIUS_PX * wp.max(p.pixel_width, p.pixel_height):
        # too small for fins and eyes to show: a plain oval along the heading, five times cheaper
        if in_ellipse(u, v, -0.1, 0.9, 0.4) == 1:
            return PART_BODY
        return PART_NONE
    if agent_type == PREY:
        return prey_part(u, v, p.outline * inv_r)
    return predator_part(u, v, p.outline * inv_r)


@wp.func
def sample_offset(p: RenderParams, k: int) -> wp.vec2:
    """Offset of sub-sample k (0..3) from a pixel centre, world px: a 2 x 2 grid for anti-aliasing."""
    sx = 0.25 * p.pixel_width
    sy = 0.25 * p.pixel_height
    if k == 0:
        return wp.vec2(-sx, -sy)
    if k == 1:
        return wp.vec2(sx, -sy)
    if k == 2:
        return wp.vec2(-sx, sy)
    return wp.vec2(sx, sy)


@wp.func
def is_dot(p: RenderParams, agent_type: int) -> int:
    """1 if the type's shape is too small to show (radius under DOT_RADIUS_PX image pixels): such
    agents are drawn as the single pixel under their centre, in their body colour."""
    if p.radius[agent_type] < DOT_RADIUS_PX * wp.max(p.pixel_width, p.pixel_height):
        return 1
    return 0


@wp.func
def covers(p: RenderParams, agent_type: int, d: wp.vec2, heading: wp.vec2) -> int:
    """1 if the shape covers any of the 2 x 2 sub-samples of the pixel at displacement d (world px)
    from the agent; the centre is tried first, since it decides most pixels inside the shape."""
    if shape_part(p, agent_type, d, heading) != PART_NONE:
        return 1
    k = int(0)
    while k < 4:
        if shape_part(p, agent_type, d + sample_offset(p, k), heading) != PART_NONE:
            return 1
        k = k + 1
    return 0


@wp.func
def span(lo_px: int, hi_px: int, n: int) -> int:
    """Last unwrapped index to visit from lo_px: at most n pixels, so no pixel is visited twice."""
    return wp.min(hi_px, lo_px + n - 1)


@wp.func
def pixel_box(p: RenderParams, lo: wp.vec2, hi: wp.vec2) -> wp.vec4i:
    """Unwrapped pixel rows (i0, i1) and columns (j0, j1) covering the world box lo..hi, at most one
    image wide each way (so no pixel twice)."""
    i0 = first_pixel(lo[1], 1.0 / p.pixel_height)
    j0 = first_pixel(lo[0], 1.0 / p.pixel_width)
    return wp.vec4i(
        i0,
        span(i0, last_pixel(hi[1], 1.0 / p.pixel_height), p.height_px),
        j0,
        span(j0, last_pixel(hi[0], 1.0 / p.pixel_width), p.width_px),
    )


@wp.func
def box_pixel_count(box: wp.vec4i) -> int:
    return (box[1] - box[0] + 1) * (box[3] - box[2] + 1)


@wp.func
def box_pixel(p: RenderParams, box: wp.vec4i, q: int) -> wp.vec2i:
    """Wrapped (row, column) of the q-th pixel (row by row) of `box`."""
    width = box[3] - box[2] + 1
    row = q // width
    return wp.vec2i(wrap_index(box[0] + row, p.height_px), wrap_index(box[2] + q - row * width, p.width_px))


@wp.kernel
def splat_agents(
    p: RenderParams,
    agents: Agents,
    body_key: wp.array2d(dtype=wp.int32),
    cone_count: wp.array3d(dtype=wp.int32),
    overlay: wp.array2d(dtype=wp.int32),
):
    """One thread per slot of world `p.world`.

    Inputs: the agents' position, heading, velocity and alive flags.
    Outputs (cleared by the caller): body_key `[H, W_px]` (top slot + 1, 0 = no agent),
    cone_count `[2, H, W_px]` (cones covering each pixel, by type code), overlay `[H, W_px]` (bits).
    """
    slot = wp.tid()
    w = p.world
    if not agents.alive[w, slot]:
        return
    t = PREY
    if slot >= p.prey_capacity:
        t = PREDATOR
    c = agents.position[w, slot]
    h = agents.heading[w, slot]
    key = slot + 1
    r = p.radius[t]
    dot = is_dot(p, t)
    inv_pw = 1.0 / p.pixel_width
    inv_ph = 1.0 / p.pixel_height

    # the pixel under the centre, so agents smaller than a pixel are still seen
    ci = wp.min(int(c[1] * inv_ph), p.height_px - 1)
    cj = wp.min(int(c[0] * inv_pw), p.width_px - 1)
    wp.atomic_max(body_key, ci, cj, key)

    # body (and the hit-box ring, which reaches `ring` beyond the radius)
    reach = r + 0.5 * wp.max(p.pixel_width, p.pixel_height)  # sub-samples lie up to 0.36 px out
    if p.hit_boxes != 0:
        reach = reach + p.ring
    elif dot == 1:
        reach = -1.0  # nothing more to draw: skip the loop
    reach_sq = reach * reach
    box = pixel_box(p, c - wp.vec2(reach, reach), c + wp.vec2(reach, reach))
    for n in range(box_pixel_count(box)):
        ij = box_pixel(p, box, n)
        i = ij[0]
        j = ij[1]
        d = pixel_offset(p, i, j, c)
        if wp.length_sq(d) > reach_sq:
            continue  # a corner of the bounding box
        if dot == 0:
            if covers(p, t, d, h) == 1:
                wp.atomic_max(body_key, i, j, key)
        if p.hit_boxes != 0:
            if wp.abs(wp.length(d) - r) <= p.ring:
                bit = BIT_HIT_BOX_PREY
                if t == PREDATOR:
                    bit = BIT_HIT_BOX_PREDATOR
                wp.atomic_or(overlay, i, j, bit)

    # view cone: the sector of radius view_distance and angle fov around the heading
    if p.view_cones != 0:
        vd = p.cone_radius[t]
        cos_half = p.cos_half_fov[t]
        box = pixel_box(p, c - wp.vec2(vd, vd), c + wp.vec2(vd, vd))
        for n in range(box_pixel_count(box)):
            ij = box_pixel(p, box, n)
            d = pixel_offset(p, ij[0], ij[1], c)
            dist = wp.length(d)
            if dist <= vd and wp.dot(d, h) >= cos_half * dist:
                wp.atomic_add(cone_count, t, ij[0], ij[1], 1)

    # velocity arrow from the centre along velocity * velocity_scale
    if p.velocities != 0:
        draw_arrow(p, c, agents.velocity[w, slot] * p.velocity_scale, overlay, BIT_VELOCITY)


@wp.func
def draw_arrow(p: RenderParams, c: wp.vec2, v: wp.vec2, overlay: wp.array2d(dtype=wp.int32), bit: int):
    """Mark `bit` on the pixels of an arrow from `c` along `v` (world px), measured in image pixels so
    it stays a thin line at any zoom; shorter than a pixel: nothing."""
    inv_pw = 1.0 / p.pixel_width
    inv_ph = 1.0 / p.pixel_height
    tip = wp.vec2(v[0] * inv_pw, v[1] * inv_ph)  # image pixels
    length = wp.length(tip)
    if length >= 1.0:
        axis = tip / length
        head = wp.min(0.35 * length, 7.0)  # arrowhead length, image pixels
        pad = head * 0.5 + p.line_px + 1.0
        lo_x = c[0] + wp.min(v[0], 0.0) - pad * p.pixel_width
        hi_x = c[0] + wp.max(v[0], 0.0) + pad * p.pixel_width
        lo_y = c[1] + wp.min(v[1], 0.0) - pad * p.pixel_height
        hi_y = c[1] + wp.max(v[1], 0.0) + pad * p.pixel_height
        box = pixel_box(p, wp.vec2(lo_x, lo_y), wp.vec2(hi_x, hi_y))
        for n in range(box_pixel_count(box)):
            ij = box_pixel(p, box, n)
            d = pixel_offset(p, ij[0], ij[1], c)
            e = wp.vec2(d[0] * inv_pw, d[1] * inv_ph)  # image pixels from the centre
            along = wp.dot(e, axis)
            across = wp.abs(e[0] * axis[1] - e[1] * axis[0])
            hit = 0
            if along >= 0.0 and along <= length - head and across <= p.line_px:
                hit = 1  # shaft
            if along > length - head and along <= length:
                if across <= 0.5 * (length - along) + p.line_px * 0.5:
                    hit = 1  # arrowhead, a triangle of half width head / 2 at its base
            if hit == 1:
                wp.atomic_or(overlay, ij[0], ij[1], bit)


@wp.kernel
def splat_flow(
    p: RenderParams,
    world: WorldParams,
    w: int,
    world_step: wp.array(dtype=wp.int32),
    overlay: wp.array2d(dtype=wp.int32),
):
    """One thread per point of a grid `flow_spacing` image pixels apart: an arrow of the current there
    (docs/model.md "Flow fields", at the world's step counter: the one the next move adds), velocity_scale
    steps of drift long, at most 0.9 grid spacings. `w`: the world's index in `world`'s shard."""
    gi, gj = wp.tid()
    spacing = float(p.flow_spacing)
    c = wp.vec2((float(gj) + 0.5) * spacing * p.pixel_width, (float(gi) + 0.5) * spacing * p.pixel_height)
    v = current(world, world.values[w], c, world_step[w]) * p.velocity_scale
    longest = 0.9 * spacing * wp.min(p.pixel_width, p.pixel_height)
    length = wp.length(v)
    if length > longest:
        v = v * (longest / length)
    draw_arrow(p, c, v, overlay, BIT_FLOW)


@wp.func
def blend(base: wp.vec3, colour: wp.vec3, alpha: float) -> wp.vec3:
    return base + (colour - base) * alpha


@wp.func
def part_colour(pal: Palette, agent_type: int, part: int) -> wp.vec3:
    if agent_type == PREY:
        if part == PART_FIN:
            return pal.prey_fin
        if part == PART_EYE:
            return pal.prey_eye
        if part == PART_OUTLINE:
            return pal.prey_outline
        if part == PART_STRIPE:
            return pal.prey_stripe
        return pal.prey_body
    if part == PART_FIN:
        return pal.predator_fin
    if part == PART_EYE:
        return pal.predator_eye
    if part == PART_OUTLINE:
        return pal.predator_outline
    if part == PART_STRIPE:
        return pal.predator_stripe
    return pal.predator_body


@wp.kernel
def compose_image(
    p: RenderParams,
    pal: Palette,
    agents: Agents,
    body_key: wp.array2d(dtype=wp.int32),
    cone_count: wp.array3d(dtype=wp.int32),
    overlay: wp.array2d(dtype=wp.int32),
    image: wp.array3d(dtype=wp.uint8),
):
    """One thread per pixel (row i, column j): writes image `[H, W_px, 3]` RGB from the splat buffers."""
    i, j = wp.tid()
    colour = pal.background
    if p.view_cones != 0:
        n_pred = cone_count[PREDATOR, i, j]
        if n_pred > 0:
            colour = blend(colour, pal.predator_cone, 1.0 - wp.pow(1.0 - pal.cone_alpha[PREDATOR], float(n_pred)))
        n_prey = cone_count[PREY, i, j]
        if n_prey > 0:
            colour = blend(colour, pal.prey_cone, 1.0 - wp.pow(1.0 - pal.cone_alpha[PREY], float(n_prey)))
    bits = overlay[i, j]
    # flow arrows under everything but the cones
    if (bits & BIT_FLOW) != 0:
        colour = pal.flow
    # velocity arrows under the bodies: they start from the agent's centre
    if (bits & BIT_VELOCITY) != 0:
        colour = pal.velocity
    key = body_key[i, j]
    if key > 0:
        slot = key - 1
        t = PREY
        if slot >= p.prey_capacity:
            t = PREDATOR
        d = pixel_offset(p, i, j, agents.position[p.world, slot])
        h = agents.heading[p.world, slot]
        if is_dot(p, t) == 1:
            colour = part_colour(pal, t, PART_BODY)
        else:
            # anti-aliasing: average the 2 x 2 sub-samples, uncovered ones showing what lies beneath
            below = colour
            total = wp.vec3(0.0, 0.0, 0.0)
            covered = int(0)
            for k in range(4):
                part = shape_part(p, t, d + sample_offset(p, k), h)
                if part != PART_NONE:
                    total = total + part_colour(pal, t, part)
                    covered = covered + 1
                else:
                    total = total + below
            colour = total * 0.25
            if covered == 0:
                # marked only as the pixel under the centre of a shape thinner than the sub-samples
                colour = part_colour(pal, t, PART_BODY)
    if (bits & BIT_HIT_BOX_PREY) != 0:
        colour = pal.prey_hit_box
    if (bits & BIT_HIT_BOX_PREDATOR) != 0:
        colour = pal.predator_hit_box
    image[i, j, 0] = wp.uint8(wp.clamp(colour[0] + 0.5, 0.0, 255.0))
    image[i, j, 1] = wp.uint8(wp.clamp(colour[1] + 0.5, 0.0, 255.0))
    image[i, j, 2] = wp.uint8(wp.clamp(colour[2] + 0.5, 0.0, 255.0))


def launch_splat(params, agents, body_key, cone_count, overlay, capacity, device):
    """Splat the `capacity` slots of world `params.world` into the (cleared) buffers."""
    wp.launch(
        splat_agents, dim=capacity, inputs=[params, agents], outputs=[body_key, cone_count, overlay], device=device
    )


def launch_flow(params, world, w, world_step, overlay, device):
    """Splat the flow arrows of world `w` of the shard whose `WorldParams` are `world` into `overlay`."""
    rows = (params.height_px + params.flow_spacing - 1) // params.flow_spacing
    cols = (params.width_px + params.flow_spacing - 1) // params.flow_spacing
    wp.launch(splat_flow, dim=(rows, cols), inputs=[params, world, w, world_step], outputs=[overlay], device=device)


def launch_compose(params, palette, agents, body_key, cone_count, overlay, image, device):
    """Compose the RGB image `[H, W_px, 3]` uint8 from the splat buffers."""
    wp.launch(
        compose_image,
        dim=(params.height_px, params.width_px),
        inputs=[params, palette, agents, body_key, cone_count, overlay],
        outputs=[image],
        device=device,
    )
