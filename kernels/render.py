"""Rasteriser for one world of a batch: agents splat into per-pixel buffers, then one pass composes RGB.

Two kernels per frame, no per-agent Python:
1. `splat_agents`, one thread per agent slot of the rendered world. Each live agent visits the pixels
   of its bounding box (wrapped around the torus) and
   - writes `slot + 1` into `body_key` with `atomic_max` where its fish/shark shape covers the pixel
     centre: the highest slot wins, whatever the thread order, so overlaps are deterministic
     (predators, whose slots follow the prey's, lie on top);
   - with view cones, adds 1 to `cone_count[type]` where the pixel lies in its view sector (a count
     blends order-independently: alpha_n = 1 - (1 - alpha)^n);
   - with hit boxes / velocities, sets bits of `overlay` with `atomic_or` (same result in any order).
2. `compose_image`, one thread per pixel: background, cone tint, the winning agent's shape part
   (recomputed from its slot, so the splat needs no colour buffer), hit-box rings, velocity arrows.

Pixel (row i, column j) has its centre at world ((j + 0.5) * pixel_width, (i + 0.5) * pixel_height):
x right, y down, row 0 at the top. Each pixel test uses the torus-shortest displacement from the agent
to the pixel centre, so an agent near an edge also appears across the seam. An agent smaller than a
pixel still marks the pixel under its centre, so worlds of a million agents show every agent.
"""

import warp as wp

from .common import PREDATOR, PREY, torus_delta

wp.set_module_options({"enable_backward": False})

# Shape parts, as returned by `shape_part` (0: the pixel is outside the shape).
PART_NONE = wp.constant(0)
PART_BODY = wp.constant(1)
PART_FIN = wp.constant(2)
PART_EYE = wp.constant(3)
PART_OUTLINE = wp.constant(4)
PART_STRIPE = wp.constant(5)

# Bits of the overlay buffer.
BIT_HIT_BOX_PREDATOR = wp.constant(1)
BIT_HIT_BOX_PREY = wp.constant(2)
BIT_VELOCITY = wp.constant(4)


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
    min_radius_px: float  # shapes are drawn at least this many image pixels in radius
    outline: float  # outline thickness, world px
    ring: float  # half thickness of hit-box rings, world px
    line_px: float  # half thickness of velocity lines, image pixels
    velocity_scale: float  # velocity arrows are velocity * velocity_scale long (steps), px
    view_cones: int  # 1: draw view cones
    hit_boxes: int  # 1: draw hit boxes
    velocities: int  # 1: draw velocity arrows


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
    """Fish seen from above, nose at +u: oval body, forked tail, two eyes, a dorsal stripe.
    (u, v) and `edge` (outline thickness) are in units of the hit-box radius; the shape fits in the
    unit circle."""
    av = wp.abs(v)
    # eyes near the nose, one each side
    du = u - 0.42
    dv = av - 0.17
    if du * du + dv * dv <= 0.075 * 0.075:
        return PART_EYE
    if in_ellipse(u, av, 0.1, 0.62, 0.36) == 1:
        if in_ellipse(u, av, 0.1, wp.max(0.62 - edge, 1e-3), wp.max(0.36 - edge, 1e-3)) == 0:
            return PART_OUTLINE
        # a darker dorsal stripe on the back half
        if av < 0.05 and u < 0.25 and u > -0.4:
            return PART_STRIPE
        return PART_BODY
    # forked tail: a wedge from the body's back to u = -0.93, with a notch cut into its trailing edge
    if in_triangle(wp.vec2(u, av), wp.vec2(-0.4, 0.0), wp.vec2(-0.93, 0.36), wp.vec2(-0.93, 0.0)) == 1:
        if in_triangle(wp.vec2(u, av), wp.vec2(-0.74, 0.0), wp.vec2(-0.94, 0.2), wp.vec2(-0.94, 0.0)) == 0:
            return PART_FIN
    # small pectoral fins behind the eyes
    if in_triangle(wp.vec2(u, av), wp.vec2(0.2, 0.3), wp.vec2(-0.05, 0.33), wp.vec2(-0.12, 0.52)) == 1:
        return PART_FIN
    return PART_NONE


@wp.func
def predator_part(u: float, v: float, edge: float) -> int:
    """Shark seen from above, nose at +u: slim pointed body, swept pectoral fins, a crescent tail,
    a dorsal fin along the spine, eyes on the snout. Units as in `prey_part`."""
    av = wp.abs(v)
    du = u - 0.58
    dv = av - 0.1
    if du * du + dv * dv <= 0.045 * 0.045:
        return PART_EYE
    # body: an ellipse, sharpened towards the snout by narrowing it ahead of u = 0.3
    half = 0.24
    if u > 0.3:
        half = 0.24 * (1.0 - 0.35 * (u - 0.3) / 0.6)
    if in_ellipse(u, av, 0.05, 0.85, half) == 1:
        if in_ellipse(u, av, 0.05, wp.max(0.85 - edge, 1e-3), wp.max(half - edge, 1e-3)) == 0:
            return PART_OUTLINE
        # dorsal fin seen from above: a narrow darker wedge on the spine
        if in_triangle(wp.vec2(u, av), wp.vec2(0.2, 0.0), wp.vec2(-0.15, 0.07), wp.vec2(-0.3, 0.0)) == 1:
            return PART_STRIPE
        return PART_BODY
    # pectoral fins: swept-back triangles on both sides
    if in_triangle(wp.vec2(u, av), wp.vec2(0.32, 0.15), wp.vec2(0.02, 0.18), wp.vec2(-0.3, 0.66)) == 1:
        return PART_FIN
    # small pelvic fins
    if in_triangle(wp.vec2(u, av), wp.vec2(-0.42, 0.12), wp.vec2(-0.55, 0.1), wp.vec2(-0.62, 0.26)) == 1:
        return PART_FIN
    # crescent tail: two lobes meeting on the tail stalk
    if in_triangle(wp.vec2(u, av), wp.vec2(-0.7, 0.0), wp.vec2(-0.92, 0.38), wp.vec2(-0.86, 0.0)) == 1:
        return PART_FIN
    return PART_NONE


@wp.func
def shape_part(agent_type: int, d: wp.vec2, heading: wp.vec2, radius: float, edge: float) -> int:
    """Part of an agent's shape at displacement d (world px) from its centre, 0 if outside."""
    h = heading
    if wp.length_sq(h) < 1e-12:
        h = wp.vec2(0.0, -1.0)  # no heading recorded: point up
    inv_r = 1.0 / radius
    u = (d[0] * h[0] + d[1] * h[1]) * inv_r
    v = (d[1] * h[0] - d[0] * h[1]) * inv_r
    if agent_type == PREY:
        return prey_part(u, v, edge * inv_r)
    return predator_part(u, v, edge * inv_r)


@wp.func
def draw_radius(p: RenderParams, agent_type: int) -> float:
    """Radius the shape is drawn at: the hit box, but at least `min_radius_px` image pixels."""
    return wp.max(p.radius[agent_type], p.min_radius_px * wp.max(p.pixel_width, p.pixel_height))


@wp.func
def span(lo_px: int, hi_px: int, n: int) -> int:
    """Last unwrapped index to visit from lo_px: at most n pixels, so no pixel is visited twice."""
    return wp.min(hi_px, lo_px + n - 1)


@wp.kernel
def splat_agents(
    p: RenderParams,
    position: wp.array2d(dtype=wp.vec2),
    heading: wp.array2d(dtype=wp.vec2),
    velocity: wp.array2d(dtype=wp.vec2),
    alive: wp.array2d(dtype=wp.bool),
    body_key: wp.array2d(dtype=wp.int32),
    cone_count: wp.array3d(dtype=wp.int32),
    overlay: wp.array2d(dtype=wp.int32),
):
    """One thread per slot of world `p.world`.

    Inputs: position, heading, velocity, alive `[W, C]` (px, unit vectors, px/step).
    Outputs (cleared by the caller): body_key `[H, W_px]` (top slot + 1, 0 = no agent),
    cone_count `[2, H, W_px]` (cones covering each pixel, by type code), overlay `[H, W_px]` (bits).
    """
    slot = wp.tid()
    w = p.world
    if not alive[w, slot]:
        return
    t = PREY
    if slot >= p.prey_capacity:
        t = PREDATOR
    c = position[w, slot]
    h = heading[w, slot]
    key = slot + 1
    r = draw_radius(p, t)
    inv_pw = 1.0 / p.pixel_width
    inv_ph = 1.0 / p.pixel_height

    # the pixel under the centre, so agents smaller than a pixel are still seen
    ci = wp.min(int(c[1] * inv_ph), p.height_px - 1)
    cj = wp.min(int(c[0] * inv_pw), p.width_px - 1)
    wp.atomic_max(body_key, ci, cj, key)

    # body (and the hit-box ring, which reaches `ring` beyond the radius)
    reach = r
    if p.hit_boxes != 0:
        reach = wp.max(r, p.radius[t] + p.ring)
    i0 = first_pixel(c[1] - reach, inv_ph)
    i1 = span(i0, last_pixel(c[1] + reach, inv_ph), p.height_px)
    j0 = first_pixel(c[0] - reach, inv_pw)
    j1 = span(j0, last_pixel(c[0] + reach, inv_pw), p.width_px)
    for ii in range(i0, i1 + 1):
        i = wrap_index(ii, p.height_px)
        for jj in range(j0, j1 + 1):
            j = wrap_index(jj, p.width_px)
            d = pixel_offset(p, i, j, c)
            if shape_part(t, d, h, r, p.outline) != PART_NONE:
                wp.atomic_max(body_key, i, j, key)
            if p.hit_boxes != 0:
                if wp.abs(wp.length(d) - p.radius[t]) <= p.ring:
                    bit = BIT_HIT_BOX_PREY
                    if t == PREDATOR:
                        bit = BIT_HIT_BOX_PREDATOR
                    wp.atomic_or(overlay, i, j, bit)

    # view cone: the sector of radius view_distance and angle fov around the heading
    if p.view_cones != 0:
        vd = p.cone_radius[t]
        cos_half = p.cos_half_fov[t]
        i0 = first_pixel(c[1] - vd, inv_ph)
        i1 = span(i0, last_pixel(c[1] + vd, inv_ph), p.height_px)
        j0 = first_pixel(c[0] - vd, inv_pw)
        j1 = span(j0, last_pixel(c[0] + vd, inv_pw), p.width_px)
        for ii in range(i0, i1 + 1):
            i = wrap_index(ii, p.height_px)
            for jj in range(j0, j1 + 1):
                j = wrap_index(jj, p.width_px)
                d = pixel_offset(p, i, j, c)
                dist = wp.length(d)
                if dist <= vd and wp.dot(d, h) >= cos_half * dist:
                    wp.atomic_add(cone_count, t, i, j, 1)

    # velocity arrow from the centre along velocity * velocity_scale, measured in image pixels so
    # it stays a thin line at any zoom
    if p.velocities != 0:
        v = velocity[w, slot] * p.velocity_scale
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
            i0 = first_pixel(lo_y, inv_ph)
            i1 = span(i0, last_pixel(hi_y, inv_ph), p.height_px)
            j0 = first_pixel(lo_x, inv_pw)
            j1 = span(j0, last_pixel(hi_x, inv_pw), p.width_px)
            for ii in range(i0, i1 + 1):
                i = wrap_index(ii, p.height_px)
                for jj in range(j0, j1 + 1):
                    j = wrap_index(jj, p.width_px)
                    d = pixel_offset(p, i, j, c)
                    q = wp.vec2(d[0] * inv_pw, d[1] * inv_ph)  # image pixels from the centre
                    along = wp.dot(q, axis)
                    across = wp.abs(q[0] * axis[1] - q[1] * axis[0])
                    hit = 0
                    if along >= 0.0 and along <= length - head and across <= p.line_px:
                        hit = 1  # shaft
                    if along > length - head and along <= length:
                        if across <= 0.5 * (length - along) + p.line_px * 0.5:
                            hit = 1  # arrowhead, a triangle of half width head / 2 at its base
                    if hit == 1:
                        wp.atomic_or(overlay, i, j, BIT_VELOCITY)


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
    position: wp.array2d(dtype=wp.vec2),
    heading: wp.array2d(dtype=wp.vec2),
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
    key = body_key[i, j]
    if key > 0:
        slot = key - 1
        t = PREY
        if slot >= p.prey_capacity:
            t = PREDATOR
        d = pixel_offset(p, i, j, position[p.world, slot])
        part = shape_part(t, d, heading[p.world, slot], draw_radius(p, t), p.outline)
        # part 0: the pixel was only marked as the centre of an agent smaller than a pixel
        colour = part_colour(pal, t, part)
    bits = overlay[i, j]
    if (bits & BIT_HIT_BOX_PREY) != 0:
        colour = pal.prey_hit_box
    if (bits & BIT_HIT_BOX_PREDATOR) != 0:
        colour = pal.predator_hit_box
    if (bits & BIT_VELOCITY) != 0:
        colour = pal.velocity
    image[i, j, 0] = wp.uint8(wp.clamp(colour[0] + 0.5, 0.0, 255.0))
    image[i, j, 1] = wp.uint8(wp.clamp(colour[1] + 0.5, 0.0, 255.0))
    image[i, j, 2] = wp.uint8(wp.clamp(colour[2] + 0.5, 0.0, 255.0))


def launch_splat(params, position, heading, velocity, alive, body_key, cone_count, overlay, capacity, device):
    """Splat the `capacity` slots of world `params.world` into the (cleared) buffers."""
    wp.launch(splat_agents, dim=capacity, inputs=[params, position, heading, velocity, alive],
              outputs=[body_key, cone_count, overlay], device=device)


def launch_compose(params, palette, position, heading, body_key, cone_count, overlay, image, device):
    """Compose the RGB image `[H, W_px, 3]` uint8 from the splat buffers."""
    wp.launch(compose_image, dim=(params.height_px, params.width_px),
              inputs=[params, palette, position, heading, body_key, cone_count, overlay],
              outputs=[image], device=device)
