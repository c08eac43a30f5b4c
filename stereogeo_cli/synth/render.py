"""The per-process renderer: GL programs, the texture pool, panoramas, and drawing a scene from a camera.

Colour is rendered with multisample anti-aliasing and mipmapped, anisotropic textures; depth (optional)
in a second, single-sample pass that writes the camera z in metres (0 where the panorama is seen).
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import numpy as np

from stereogeo_cli.synth.gl import as_uniform, get_context, projection_matrix, view_matrix
from stereogeo_cli.synth.rigs import Camera
from stereogeo_cli.synth.scenes import MaterialIndex, Scene
from stereogeo_cli.synth.textures import build_material_pool, looks_like_sky, procedural_sky, read_rgb

_SKY_LOOKUP = """
uniform sampler2D sky;
uniform float sky_yaw;
const float PI = 3.14159265358979;
vec3 sky_color(vec3 d) {
    d = normalize(d);
    float s = 0.5 - atan(d.y, d.x) / (2.0 * PI) + sky_yaw;
    float t = 0.5 - asin(clamp(d.z, -1.0, 1.0)) / PI;
    // derivatives that ignore the wrap of the longitude, so the seam gets no coarse mip level
    float s2 = fract(s + 0.5);
    vec2 dx = vec2(dFdx(s), dFdx(t)), dy = vec2(dFdy(s), dFdy(t));
    float dx2 = dFdx(s2), dy2 = dFdy(s2);
    if (abs(dx2) + abs(dy2) < abs(dx.x) + abs(dy.x)) { dx.x = dx2; dy.x = dy2; }
    return textureGrad(sky, vec2(s, t), dx, dy).rgb;
}
"""

_SURFACE_VS = """
#version 330
uniform mat4 mvp;
in vec3 in_pos; in vec3 in_normal; in vec2 in_uv; in float in_layer; in vec3 in_tint; in float in_mirror;
out vec3 v_pos; out vec3 v_normal; out vec2 v_uv; out vec3 v_tint;
flat out float v_layer; flat out float v_mirror;
void main() {
    gl_Position = mvp * vec4(in_pos, 1.0);
    v_pos = in_pos; v_normal = in_normal; v_uv = in_uv; v_tint = in_tint;
    v_layer = in_layer; v_mirror = in_mirror;
}
"""

_SURFACE_FS = """
#version 330
uniform sampler2DArray materials;
uniform float ambient; uniform float strength; uniform vec3 sun; uniform vec3 lamp; uniform float use_lamp;
uniform float falloff; uniform vec3 eye; uniform float grime_layer; uniform float grime;
in vec3 v_pos; in vec3 v_normal; in vec2 v_uv; flat in float v_layer; in vec3 v_tint; flat in float v_mirror;
out vec4 color;
vec3 material(vec2 uv, vec2 dx, vec2 dy) {
    if (v_mirror > 0.5) uv = 1.0 - abs(mod(uv, 2.0) - 1.0);  // mirrored repeat: photos without seams
    return textureGrad(materials, vec3(uv, v_layer), dx, dy).rgb;
}
void main() {
    vec2 dx = dFdx(v_uv), dy = dFdy(v_uv);
    // cheap anisotropic filtering (llvmpipe's own is very slow): on surfaces seen at a grazing angle,
    // two taps along the long axis of the pixel footprint, each with a footprint half as long
    float lx = length(dx), ly = length(dy);
    vec3 albedo;
    if (max(lx, ly) > 2.0 * min(lx, ly)) {
        vec2 major = lx > ly ? dx : dy;
        vec2 hx = lx > ly ? dx * 0.5 : dx, hy = lx > ly ? dy : dy * 0.5;
        albedo = 0.5 * (material(v_uv - 0.25 * major, hx, hy) + material(v_uv + 0.25 * major, hx, hy));
    } else {
        albedo = material(v_uv, dx, dy);
    }
    albedo *= v_tint;
    const float k = 0.37;  // the wear pattern repeats every 2.7 material tiles, out of step with them
    float wear = textureGrad(materials, vec3(v_uv * k + 0.13 * v_layer, grime_layer), dx * k, dy * k).r;
    albedo *= 1.0 + (wear - 0.5) * grime * (v_mirror > 0.5 ? 0.4 : 1.0);
    vec3 n = normalize(v_normal);
    if (dot(n, eye - v_pos) < 0.0) n = -n;  // light the side that is seen
    float light;
    if (use_lamp > 0.5) {
        vec3 to_lamp = lamp - v_pos;
        float d = length(to_lamp);
        light = max(dot(n, to_lamp / d), 0.0) / (1.0 + (d / falloff) * (d / falloff));
    } else {
        light = max(dot(n, sun), 0.0);
    }
    float shade = ambient + strength * light + 0.08 * n.z;
    color = vec4(albedo * shade, 1.0);
}
"""

_WINDOW_VS = """
#version 330
uniform mat4 mvp;
in vec3 in_pos;
out vec3 v_pos;
void main() { gl_Position = mvp * vec4(in_pos, 1.0); v_pos = in_pos; }
"""

_WINDOW_FS = (
    """
#version 330
uniform vec3 eye;
in vec3 v_pos;
out vec4 color;
"""
    + _SKY_LOOKUP
    + """
void main() { color = vec4(sky_color(v_pos - eye), 1.0); }
"""
)

_SKY_VS = """
#version 330
in vec2 in_vert;
void main() { gl_Position = vec4(in_vert, 1.0, 1.0); }
"""

_SKY_FS = (
    """
#version 330
uniform mat3 R_cw; uniform vec4 intrinsics;  // (fx, fy, cx, cy)
out vec4 color;
"""
    + _SKY_LOOKUP
    + """
void main() {
    // GL row 0 is image row 0, and OpenCV pixel centres sit at integer coordinates
    vec2 p = gl_FragCoord.xy - 0.5;
    vec3 ray = vec3((p.x - intrinsics.z) / intrinsics.x, (p.y - intrinsics.w) / intrinsics.y, 1.0);
    color = vec4(sky_color(R_cw * ray), 1.0);
}
"""
)

_DEPTH_VS = """
#version 330
uniform mat4 mvp; uniform mat4 view;
in vec3 in_pos;
out float v_z;
void main() { gl_Position = mvp * vec4(in_pos, 1.0); v_z = (view * vec4(in_pos, 1.0)).z; }
"""

_DEPTH_FS = """
#version 330
in float v_z;
out float depth;
void main() { depth = v_z; }
"""


PROCEDURAL_SKIES = 8  # procedural skies per process (used without --panoramas)


class Renderer:
    """Everything GL of one process. Build once (it uploads the texture pool) and reuse for every pair."""

    def __init__(
        self,
        seed: int,
        texture_size: int = 512,
        texture_layers: int = 48,
        textures_dir: Path | None = None,
        panorama_files: list[Path] | None = None,
        panorama_cache: int = 12,
        msaa: int = 4,
    ):
        import moderngl

        self.ctx = ctx = get_context()
        self.msaa = msaa
        self.panorama_files = list(panorama_files or [])
        pool = build_material_pool(seed, texture_size, texture_layers, textures_dir, self.panorama_files)
        self.materials = MaterialIndex(pool)
        data = np.stack([m.image for m in pool])
        self.texture = ctx.texture_array((texture_size, texture_size, len(pool)), 3, data.tobytes())
        self.texture.build_mipmaps()
        self.texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self.texture.anisotropy = 1.0
        self.surface = ctx.program(vertex_shader=_SURFACE_VS, fragment_shader=_SURFACE_FS)
        self.window = ctx.program(vertex_shader=_WINDOW_VS, fragment_shader=_WINDOW_FS)
        self.sky = ctx.program(vertex_shader=_SKY_VS, fragment_shader=_SKY_FS)
        self.depth = ctx.program(vertex_shader=_DEPTH_VS, fragment_shader=_DEPTH_FS)
        self.surface["materials"] = 0
        self.surface["grime_layer"] = float(len(pool) - 1)
        for program in (self.window, self.sky):
            program["sky"] = 1
        triangle = ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], dtype="f4").tobytes())
        self.sky_vao = ctx.vertex_array(self.sky, [(triangle, "2f", "in_vert")])
        self.seed = seed
        self._procedural: dict[int, np.ndarray] = {}
        n = len(self.panorama_files)
        outdoor = [i for i, path in enumerate(self.panorama_files) if looks_like_sky(read_rgb(path))]
        procedural = list(range(n, n + PROCEDURAL_SKIES))
        self.sky_choices = {
            "outdoor": outdoor or procedural,
            "window": outdoor or procedural,
            "panorama": list(range(n)),
        }
        self._panoramas: OrderedDict[int, object] = OrderedDict()
        self._panorama_cache = max(1, panorama_cache)
        self._targets: dict[tuple[int, int], tuple] = {}

    # --- resources ------------------------------------------------------------------------------------

    def sky_name(self, index: int) -> str:
        n = len(self.panorama_files)
        return self.panorama_files[index].stem if index < n else f"procedural-sky-{index - n}"

    def panorama_width(self, index: int) -> int:
        """Width in pixels of sky ``index`` (panorama files first, then the 1024-wide procedural skies)."""
        return self._sky_texture(index).width

    def _sky_image(self, index: int) -> np.ndarray:
        n = len(self.panorama_files)
        if index < n:
            return read_rgb(self.panorama_files[index])
        k = index - n
        if k not in self._procedural:
            self._procedural[k] = procedural_sky(np.random.default_rng([self.seed, 0x5EED, 2, k]))
        return self._procedural[k]

    def _sky_texture(self, index: int):
        import moderngl

        if index in self._panoramas:
            self._panoramas.move_to_end(index)
            return self._panoramas[index]
        image = self._sky_image(index)
        h, w = image.shape[:2]
        texture = self.ctx.texture((w, h), 3, np.ascontiguousarray(image).tobytes())
        texture.build_mipmaps()
        texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        texture.anisotropy = 1.0
        texture.repeat_y = False
        self._panoramas[index] = texture
        while len(self._panoramas) > self._panorama_cache:
            _, old = self._panoramas.popitem(last=False)
            old.release()
        return texture

    def _target(self, width: int, height: int):
        key = (width, height)
        if key not in self._targets:
            ctx = self.ctx
            msaa = ctx.framebuffer(
                ctx.renderbuffer(key, 4, samples=self.msaa), ctx.depth_renderbuffer(key, samples=self.msaa)
            )
            resolved = ctx.framebuffer(ctx.renderbuffer(key, 4))
            depth = ctx.framebuffer(ctx.renderbuffer(key, 1, dtype="f4"), ctx.depth_renderbuffer(key))
            self._targets[key] = (msaa, resolved, depth)
        return self._targets[key]

    def upload(self, scene: Scene):
        """Vertex arrays of a scene (built once, drawn from both cameras)."""
        ctx = self.ctx
        vaos = []
        if len(scene.surfaces):
            vbo = ctx.buffer(scene.surfaces.tobytes())
            fmt = "3f 3f 2f 1f 3f 1f"
            names = ["in_pos", "in_normal", "in_uv", "in_layer", "in_tint", "in_mirror"]
            vaos.append(("surface", ctx.vertex_array(self.surface, [(vbo, fmt, *names)]), vbo))
            vaos.append(("depth", ctx.vertex_array(self.depth, [(vbo, "3f 40x", "in_pos")]), None))
        if len(scene.windows):
            wbo = ctx.buffer(scene.windows.tobytes())
            vaos.append(("window", ctx.vertex_array(self.window, [(wbo, "3f", "in_pos")]), wbo))
            vaos.append(("depth", ctx.vertex_array(self.depth, [(wbo, "3f", "in_pos")]), None))
        return vaos

    @staticmethod
    def release(vaos) -> None:
        for _, vao, buffer in vaos:
            vao.release()
            if buffer is not None:
                buffer.release()

    # --- drawing --------------------------------------------------------------------------------------

    def render_color(
        self, camera: Camera, sky_index: int, sky_yaw: float, scene: Scene | None = None, vaos=None
    ) -> np.ndarray:
        """The image [H x W x 3] uint8 RGB of a scene (or of the panorama alone) seen by ``camera``."""
        import moderngl

        ctx = self.ctx
        w, h = camera.width, camera.height
        msaa, resolved, _ = self._target(w, h)
        near, far = (scene.near, scene.far) if scene is not None else (0.05, 10.0)
        view = view_matrix(camera.R_wc, camera.center)
        mvp = projection_matrix(camera.focal, w, h, near, far, camera.fy, camera.principal) @ view
        sky = self._sky_texture(sky_index)
        sky.use(1)
        self.texture.use(0)
        msaa.use()
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE)
        ctx.depth_func = "<="
        msaa.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)
        eye = tuple(float(v) for v in camera.center)
        for name, vao, _ in vaos or []:
            if name == "surface":
                light = scene.lighting
                p = self.surface
                p["mvp"].write(as_uniform(mvp))
                p["ambient"], p["strength"] = light.ambient, light.strength
                p["sun"] = tuple(light.direction)
                p["use_lamp"] = 1.0 if light.point is not None else 0.0
                p["lamp"] = tuple(light.point) if light.point is not None else (0.0, 0.0, 0.0)
                p["falloff"] = light.falloff
                p["eye"] = eye
                p["grime"] = light.grime
                vao.render(moderngl.TRIANGLES)
            elif name == "window":
                self.window["mvp"].write(as_uniform(mvp))
                self.window["eye"] = eye
                self.window["sky_yaw"] = sky_yaw
                vao.render(moderngl.TRIANGLES)
        self.sky["R_cw"].write(np.ascontiguousarray(camera.R_wc, dtype="f4").tobytes())  # transpose = R_cw
        self.sky["intrinsics"] = (camera.focal, camera.fy, *camera.cx_cy)
        self.sky["sky_yaw"] = sky_yaw
        self.sky_vao.render(moderngl.TRIANGLES)
        ctx.copy_framebuffer(resolved, msaa)
        data = resolved.read(components=3, alignment=1)
        return np.frombuffer(data, np.uint8).reshape(h, w, 3)

    def render_depth(self, camera: Camera, scene: Scene, vaos) -> np.ndarray:
        """z-depth [H x W] float32 in metres along the camera's optical axis; 0 where nothing is hit."""
        import moderngl

        ctx = self.ctx
        w, h = camera.width, camera.height
        _, _, target = self._target(w, h)
        view = view_matrix(camera.R_wc, camera.center)
        fy, principal = camera.fy, camera.principal
        mvp = projection_matrix(camera.focal, w, h, scene.near, scene.far, fy, principal) @ view
        target.use()
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "<"
        target.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.depth["mvp"].write(as_uniform(mvp))
        self.depth["view"].write(as_uniform(view))
        for name, vao, _ in vaos:
            if name == "depth":
                vao.render(moderngl.TRIANGLES)
        data = target.read(components=1, dtype="f4", alignment=1)
        return np.frombuffer(data, np.float32).reshape(h, w).copy()
