"""The photo carried to every side: a deferred generator's texture made from the photo
before the inversion refines it.

Each texel is located on the fitted mesh and looked for in the photo twice: at its own
surface point and at its mirror image across the face (the template's vertex mirror).
Where the photo sees the point squarely and shows skin there (the fit's loss mask), the
texel takes the photo's colour, turned into albedo by the generator's own shading at that
point and the photo's light; where only the mirror point is seen, it takes that; the rest
(ears, neck, back of the head, under the chin) keeps the fitted code's skin, brought to
the tone of the skin the photo shows, with the fine detail (pores, stubble) of a real head
scan (Lee Perry-Smith's, CC BY 3.0; ``head360 build-skin-detail``). The weights fall off
smoothly with the viewing angle and are blurred in texture space, so the seams between
the three blend.
"""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F

__all__ = ["ProjectConfig", "Projection", "project_photo"]

SKIN_U = 0.74
"""Texture ``u`` below which the template's UV layout holds the head's skin (the eyes,
ears, teeth and tongue lie to the right of it)."""


@dataclasses.dataclass(frozen=True)
class ProjectConfig:
    """How a photo is projected into the texture."""

    facing_from: float = 0.25
    """Cosine between normal and view below which the photo gives a texel nothing."""
    facing_full: float = 0.6
    """Cosine from which it gives all of it (smooth in between)."""
    tolerance: float = 0.005
    """Metres a texel may lie behind the surface the photo shows and count as seen."""
    sure: float = 0.5
    """Loss-mask weight from which a pixel counts as showing skin (the fit's mask gives
    the face 1 and what it only hopes is skin around it a quarter)."""
    erode: int = 3
    """Pixels that mask is shrunk by first, so that its edge (hairline, collar, backdrop)
    gives nothing."""
    blur: float = 1.5
    """Texels: the Gaussian blur of the weights that blends the seams."""
    match: float = 0.05
    """The reach (Gaussian sigma, a share of the texture's side: 12.8 texels at 256)
    over which the filled skin next to what the photo shows takes on the photo's skin's
    colour, fading out beyond (0: none). The fill's one tone for the whole head left a
    seam of another colour along the jaw and the cheeks' sides."""


@dataclasses.dataclass
class Projection:
    """A projected texture ``(1, C, R, R)`` and where its colours came from: ``photo``
    and ``mirror`` ``(R, R)`` weights in [0, 1] of the direct and the mirrored reads
    (the rest of the ``covered (R, R)`` texels: the code's skin), and ``tone (3,)`` the
    gain that brought the code's skin to the photo's."""

    texture: torch.Tensor
    photo: torch.Tensor
    mirror: torch.Tensor
    tone: torch.Tensor
    covered: torch.Tensor


MATCH_FULL = 0.5
"""Blurred weight of the photo's skin from which the fill takes all of its colour (at a
straight edge of what the photo shows, the blurred weight is 0.5)."""


def _smooth(x: torch.Tensor, lo: float, hi: float) -> torch.Tensor:
    t = ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
    return t * t * (3 - 2 * t)


def _blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """``(R, R)`` blurred by a Gaussian of ``sigma`` texels."""
    if sigma <= 0:
        return x
    r = max(1, int(3 * sigma))
    t = torch.arange(-r, r + 1, dtype=x.dtype, device=x.device)
    g = torch.exp(-0.5 * (t / sigma) ** 2)
    g = g / g.sum()
    y = F.conv2d(x[None, None], g.view(1, 1, 1, -1), padding=(0, r))
    return F.conv2d(y, g.view(1, 1, -1, 1), padding=(r, 0))[0, 0]


def _skin_detail(res: int, like: torch.Tensor) -> torch.Tensor | None:
    """``(res, res, 3)`` the shipped scan's fine skin detail, or ``None``."""
    from head360cli.synth.skin import skin_detail

    fine = skin_detail(res)
    return None if fine is None else torch.as_tensor(fine).to(like)


def _albedo(gen, feats: torch.Tensor, colour: torch.Tensor, normal: torch.Tensor,
            view: torch.Tensor) -> torch.Tensor:
    """Albedo ``(N, 3)`` whose shading by ``gen``'s pixel shader at ``normal`` and
    ``view`` (with the other channels ``feats (N, C)``) gives ``colour (N, 3)``."""
    hair = torch.zeros_like(normal[:, :1])
    _, residual = gen.shader(feats, normal, view, hair)
    light = gen.shader.shading(normal, view, hair).clamp_min(0.05)
    return ((colour - residual) / light).clamp(0.0, 1.0)


@torch.no_grad()
def project_photo(gen, verts: torch.Tensor, mirror: torch.Tensor, c2w: torch.Tensor,
                  intrinsics: torch.Tensor, photo: torch.Tensor, mask: torch.Tensor,
                  start: torch.Tensor, light: torch.Tensor | None = None,
                  cfg: ProjectConfig = ProjectConfig()) -> Projection:
    """Project a photo into a deferred generator's texture.

    Args:
        gen: The :class:`~head360cli.model.deferred.DeferredGenerator`.
        verts: ``(V, 3)`` the fitted mesh; ``mirror (V,)`` each vertex's mirror vertex.
        c2w: ``(4, 4)`` the photo's camera, ``intrinsics (3, 3)`` for ``photo``'s size.
        photo: ``(3, H, W)`` in [0, 1]; ``mask (1, H, W)`` the fit's loss weights (those
            from ``cfg.sure`` on count as skin).
        start: ``(1, C, R, R)`` the fitted code's texture.
        light: ``(3,)`` the photo's light (the fit's colour gain), or ``None``.
        cfg: Angles, tolerance, seams.

    Returns:
        The :class:`Projection`; channels after the first three are ``start``'s.
    """
    from head360cli.geometry.mesh_ops import vertex_normals
    from head360cli.geometry.texels import seen_in_photo, texel_surface

    res = start.shape[-1]
    faces = gen.faces
    normals = vertex_normals(verts[None], faces, gen.normal_groups)[0]
    surf = texel_surface(verts, faces, gen.uv, gen.faces_uv, res, normals)
    with gen.image_size(None), gen.pixel_samples(1):
        size = photo.shape[-1]
        with gen._override(image_res=size, render_res=size):
            buf = gen.gbuffer(verts[None], c2w[None], intrinsics[None])
    depth = torch.where(buf.mask[0], buf.depth[0], torch.zeros_like(buf.depth[0]))
    valid = (mask >= cfg.sure).to(photo.dtype)
    if cfg.erode > 0:
        valid = -F.max_pool2d(-valid[None], 2 * cfg.erode + 1, 1, cfg.erode)[0]
    image = torch.cat([photo if light is None else photo / light.view(3, 1, 1), valid])
    covered = surf.covered.reshape(-1)
    idx = torch.nonzero(covered).squeeze(1)
    feats = start[0].permute(1, 2, 0).reshape(-1, start.shape[1]).index_select(0, idx)
    eye = c2w[:3, 3]

    def read(points: torch.Tensor, normal: torch.Tensor) -> tuple[torch.Tensor,
                                                                   torch.Tensor]:
        values, facing, visible = seen_in_photo(points, normal, image, c2w, intrinsics,
                                                depth, cfg.tolerance)
        weight = _smooth(facing, cfg.facing_from, cfg.facing_full) * visible * values[:, 3]
        view = F.normalize(eye[None] - points, dim=-1)
        return _albedo(gen, feats, values[:, :3], normal, view), weight

    points = surf.points.reshape(-1, 3).index_select(0, idx)
    normal = surf.normals.reshape(-1, 3).index_select(0, idx)
    own, w_own = read(points, normal)
    m_points = surf.at(verts[mirror], faces).reshape(-1, 3).index_select(0, idx)
    m_normal = F.normalize(surf.at(normals[mirror], faces).reshape(-1, 3).index_select(
        0, idx), dim=-1)
    other, w_other = read(m_points, m_normal)

    def texels(values: torch.Tensor) -> torch.Tensor:
        out = values.new_zeros(res * res, *values.shape[1:])
        return out.index_copy(0, idx, values).view(res, res, *values.shape[1:])

    def blended(values: torch.Tensor, weight: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """Weights blurred over the seams, and the colours under them averaged by weight
        (so that a blurred weight never reaches a colour the photo did not give)."""
        w = texels(weight)
        spread = _blur(w, cfg.blur)
        mean = torch.stack([_blur(w * c, cfg.blur) for c in texels(values).unbind(-1)], -1)
        return mean / spread.clamp_min(1e-6)[..., None], spread.clamp(0, 1) * surf.covered

    own_t, w_photo = blended(own, w_own)
    other_t, w_mirror = blended(other, w_other)
    # the code's skin toned to the skin the photo shows squarely
    base = start[0, :3].permute(1, 2, 0)
    u = (torch.arange(res, dtype=photo.dtype, device=photo.device) + 0.5) / res
    skin_part = (u[None, :] < SKIN_U).expand(res, res)
    skin = surf.covered & skin_part & (texels(w_own) > 0.9)
    if int(skin.sum()) >= 16:
        seen = texels(own)[skin]
        tone = (seen.median(0).values / base[skin].median(0).values.clamp_min(1e-3)
                ).clamp(0.25, 4.0)
    else:
        tone = torch.ones(3, dtype=photo.dtype, device=photo.device)
    toned = base * tone
    if cfg.match > 0:  # the seen skin's low frequencies carried into the fill beside it
        w = texels(w_own) * skin_part
        sigma = cfg.match * res
        spread = _blur(w, sigma)
        diff = texels(own) - toned
        near = torch.stack([_blur(w * d, sigma) for d in diff.unbind(-1)], -1)
        fade = (spread / MATCH_FULL).clamp(0, 1)[..., None]
        toned = toned + fade * near / spread.clamp_min(1e-6)[..., None]
    detail = _skin_detail(res, toned)
    if detail is not None:  # the scan's pores where the code's painted skin has none
        toned = toned * detail
    fill = torch.where(skin_part[..., None], toned.clamp(0, 1), base)
    direct = w_photo[..., None]
    mirrored = ((1 - w_photo) * w_mirror)[..., None]
    albedo = direct * own_t + mirrored * other_t + (1 - direct - mirrored) * fill
    albedo = torch.where(surf.covered[..., None], albedo, base)
    texture = start.clone()
    texture[0, :3] = albedo.permute(2, 0, 1)
    return Projection(texture, w_photo, (1 - w_photo) * w_mirror, tone, surf.covered)
