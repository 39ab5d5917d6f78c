#!/usr/bin/env python3
"""Writes the glTF 2.0 sample scenes in samples/scenes/gltf/ and their TOML twins.

    python3 tools/gltf-samples.py        # from the repository root; standard library only

Three scenes after samples/scenes/ (glass-sphere, cognac, reflector), as a user would bring
them from Blender: triangle meshes under a node hierarchy, KHR_lights_punctual lights in
photometric units, transmissive / metallic / diffuse materials. Each is written in a
different container: glass-sphere.gltf with an external glass-sphere.bin, cognac.glb, and
reflector.gltf with its buffer in a data: URI.

Each scene has a TOML twin in samples/scenes/gltf/twins/ that describes the same scene in
photonkit's own format: the same triangles (in OBJ files, the vertex order kept), the same
node translations as `transform = { translate = … }`, the lights' watts as photonkit computes
them from the glTF intensities (LUMENS_PER_WATT = 683; docs/scene.md, "glTF scenes"). Every
number both files hold is an f32 written exactly (the shortest decimal of its double), so both
readers get the same bits, and `photonkit trace` gives the same photons from either (the test
suite checks: tests/suite/gltf.rs). The twins differ from the originals in samples/scenes/
where glTF cannot follow them: the analytic sphere and floors are meshes here.
"""

import base64
import json
import math
import os
import struct

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "samples", "scenes", "gltf")
LUMENS_PER_WATT = 683.0


def f32(x):
    """x rounded to f32 (as a Python float), negative zero made positive."""
    return struct.unpack("<f", struct.pack("<f", x))[0] + 0.0


def num(x):
    """An f32 value as the shortest decimal of its double: parses to the same f32 anywhere."""
    return repr(f32(x))


def f32_to_radians(deg):
    """Rust's f32::to_radians: deg × (π/180 rounded to f32), rounded to f32."""
    return f32(f32(deg) * f32(f32(math.pi) / 180.0))


class Mesh:
    def __init__(self, positions, triangles, normals=None):
        # Renumber the vertices in order of first use, as an OBJ reader does, and drop unused.
        order, seen = [], {}
        for t in triangles:
            for k in t:
                if k not in seen:
                    seen[k] = len(order)
                    order.append(k)
        self.positions = [tuple(f32(c) for c in positions[k]) for k in order]
        self.normals = None
        if normals is not None:
            self.normals = []
            for k in order:
                n = normals[k]
                ln = math.sqrt(sum(c * c for c in n))
                self.normals.append(tuple(f32(c / ln) for c in n))
        self.triangles = [tuple(seen[k] for k in t) for t in triangles]

    def obj(self):
        lines = ["# written by tools/gltf-samples.py: the same triangles as the glTF twin"]
        lines += ["v %s %s %s" % tuple(num(c) for c in p) for p in self.positions]
        if self.normals:
            lines += ["vn %s %s %s" % tuple(num(c) for c in n) for n in self.normals]
            lines += ["f %d//%d %d//%d %d//%d" % tuple(k + 1 for k in t for _ in (0, 1)) for t in self.triangles]
        else:
            lines += ["f %d %d %d" % tuple(k + 1 for k in t) for t in self.triangles]
        return "\n".join(lines) + "\n"


def quad(x0, y0, x1, y1, z):
    return Mesh([(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)], [(0, 1, 2), (0, 2, 3)])


def uv_sphere(radius, segments, rings):
    pos, nrm, tris = [], [], []
    for j in range(rings + 1):
        th = math.pi * j / rings
        for i in range(segments):
            ph = 2 * math.pi * i / segments
            n = (math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th))
            pos.append(tuple(radius * c for c in n))
            nrm.append(n)
    at = lambda i, j: j * segments + i % segments
    for j in range(rings):
        for i in range(segments):
            a, b, c, d = at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)
            if j > 0:
                tris.append((a, c, b))
            if j < rings - 1:
                tris.append((a, d, c))
    return Mesh(pos, tris, nrm)


def revolution(profile, segments, crease_deg, smooth=True):
    """A profile of (r, z) points turned about z; the solid on the walker's left (as
    photonkit's `revolution` shape; corners sharper than crease_deg keep their normals)."""
    seg_n = []
    for (r0, z0), (r1, z1) in zip(profile, profile[1:]):
        n = (z1 - z0, r0 - r1)
        ln = math.hypot(*n)
        seg_n.append((n[0] / ln, n[1] / ln))
    cos_crease = math.cos(math.radians(crease_deg))
    pos, nrm, tris = [], [], []

    def ring(p, n):
        start = len(pos)
        for s in range(segments):
            ph = 2 * math.pi * s / segments
            c, si = math.cos(ph), math.sin(ph)
            pos.append((p[0] * c, p[0] * si, p[1]))
            nrm.append((n[0] * c, n[0] * si, n[1]))
        return start

    for k in range(len(profile) - 1):
        own = seg_n[k]

        def end_normal(j):
            if j is not None and 0 <= j < len(seg_n):
                o = seg_n[j]
                if o[0] * own[0] + o[1] * own[1] >= cos_crease:
                    s = (o[0] + own[0], o[1] + own[1])
                    ln = math.hypot(*s)
                    return (s[0] / ln, s[1] / ln)
            return own

        a = ring(profile[k], end_normal(k - 1 if k > 0 else None))
        b = ring(profile[k + 1], end_normal(k + 1))
        for s in range(segments):
            s1 = (s + 1) % segments
            for t in ((a + s, a + s1, b + s1), (a + s, b + s1, b + s)):
                p = [pos[i] for i in t]
                e1 = [p[1][i] - p[0][i] for i in range(3)]
                e2 = [p[2][i] - p[0][i] for i in range(3)]
                cr = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0])
                if sum(c * c for c in cr) > 1e-24:  # the poles' zero-area triangles
                    tris.append(t)
    return Mesh(pos, tris, nrm if smooth else None)


def paraboloid_down(focal, r_min, r_max, rings, segments, vertex_z):
    """The faceted reflector z = vertex_z − r²/(4f), opening downwards, flat facets."""
    pos, tris = [], []
    for k in range(rings + 1):
        r = r_min + (r_max - r_min) * k / rings
        for s in range(segments):
            ph = 2 * math.pi * s / segments
            pos.append((r * math.cos(ph), r * math.sin(ph), vertex_z - r * r / (4 * focal)))
    for k in range(rings):
        for s in range(segments):
            s1 = (s + 1) % segments
            a, b = k * segments, (k + 1) * segments
            tris += [(a + s, b + s1, a + s1), (a + s, b + s, b + s1)]
    return Mesh(pos, tris)


def slab(outline, z0, z1):
    """A convex polygon (counter-clockwise) extruded from z0 to z1, flat faces, outward."""
    n = len(outline)
    pos = [(x, y, z0) for x, y in outline] + [(x, y, z1) for x, y in outline]
    tris = []
    for i in range(n):
        j = (i + 1) % n
        tris += [(i, j, n + j), (i, n + j, n + i)]
    for i in range(1, n - 1):
        tris += [(n, n + i, n + i + 1), (0, i + 1, i)]
    return Mesh(pos, tris)


def look_at_quaternion(eye, target, up=(0.0, 0.0, 1.0)):
    """The rotation taking a glTF camera's −z to eye→target with +y towards `up`."""
    f = [t - e for t, e in zip(target, eye)]
    ln = math.sqrt(sum(c * c for c in f))
    f = [c / ln for c in f]
    r = (f[1] * up[2] - f[2] * up[1], f[2] * up[0] - f[0] * up[2], f[0] * up[1] - f[1] * up[0])
    ln = math.sqrt(sum(c * c for c in r))
    r = [c / ln for c in r]
    u = (r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0])
    b = [-c for c in f]
    m = [[r[0], u[0], b[0]], [r[1], u[1], b[1]], [r[2], u[2], b[2]]]  # rows; columns r, u, b
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = 2 * math.sqrt(tr + 1)
        q = ((m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, s / 4)
    else:
        i = max(range(3), key=lambda k: m[k][k])
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2 * math.sqrt(1 + m[i][i] - m[j][j] - m[k][k])
        q = [0.0, 0.0, 0.0, (m[k][j] - m[j][k]) / s]
        q[i] = s / 4
        q[j] = (m[j][i] + m[i][j]) / s
        q[k] = (m[k][i] + m[i][k]) / s
    return [num(c) for c in q]


class Gltf:
    """A glTF document being built: meshes, nodes, materials, lights, one buffer."""

    def __init__(self):
        self.doc = {"asset": {"version": "2.0", "generator": "photonkit tools/gltf-samples.py"},
                    "scene": 0, "scenes": [{"nodes": []}], "nodes": [], "meshes": [], "materials": [],
                    "accessors": [], "bufferViews": [], "buffers": []}
        self.bin = bytearray()
        self.lights = []
        self.material_index = {}

    def view(self, data, target):
        while len(self.bin) % 4:
            self.bin.append(0)
        self.doc["bufferViews"].append({"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data), "target": target})
        self.bin += data
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, view, count, kind, component, extra=None):
        a = {"bufferView": view, "componentType": component, "count": count, "type": kind}
        a.update(extra or {})
        self.doc["accessors"].append(a)
        return len(self.doc["accessors"]) - 1

    def material(self, name, m):
        if name not in self.material_index:
            self.material_index[name] = len(self.doc["materials"])
            self.doc["materials"].append(dict(name=name, **m))
        return self.material_index[name]

    def mesh(self, name, mesh, material):
        flat = [c for p in mesh.positions for c in p]
        lo = [N(min(p[i] for p in mesh.positions)) for i in range(3)]
        hi = [N(max(p[i] for p in mesh.positions)) for i in range(3)]
        pv = self.view(struct.pack("<%df" % len(flat), *flat), 34962)
        attrs = {"POSITION": self.accessor(pv, len(mesh.positions), "VEC3", 5126, {"min": lo, "max": hi})}
        if mesh.normals:
            nflat = [c for n in mesh.normals for c in n]
            nv = self.view(struct.pack("<%df" % len(nflat), *nflat), 34962)
            attrs["NORMAL"] = self.accessor(nv, len(mesh.normals), "VEC3", 5126)
        idx = [k for t in mesh.triangles for k in t]
        iv = self.view(struct.pack("<%dI" % len(idx), *idx), 34963)
        prim = {"attributes": attrs, "indices": self.accessor(iv, len(idx), "SCALAR", 5125), "material": material}
        self.doc["meshes"].append({"name": name, "primitives": [prim]})
        return len(self.doc["meshes"]) - 1

    def node(self, node, parent=None):
        self.doc["nodes"].append(node)
        i = len(self.doc["nodes"]) - 1
        if parent is None:
            self.doc["scenes"][0]["nodes"].append(i)
        else:
            self.doc["nodes"][parent].setdefault("children", []).append(i)
        return i

    def light(self, light):
        self.lights.append(light)
        return len(self.lights) - 1

    def finish(self, name, extensions):
        self.doc["scenes"][0]["name"] = name
        if self.lights:
            self.doc.setdefault("extensions", {})["KHR_lights_punctual"] = {"lights": self.lights}
        self.doc["extensionsUsed"] = extensions
        while len(self.bin) % 4:
            self.bin.append(0)
        return self.doc

    def write_gltf(self, path, name, extensions, embed):
        doc = self.finish(name, extensions)
        if embed:
            uri = "data:application/octet-stream;base64," + base64.b64encode(bytes(self.bin)).decode()
        else:
            uri = os.path.basename(path)[: -len(".gltf")] + ".bin"
            with open(os.path.join(os.path.dirname(path), uri), "wb") as f:
                f.write(self.bin)
        doc["buffers"] = [{"byteLength": len(self.bin), "uri": uri}]
        with open(path, "w") as f:
            f.write(dumps(doc))

    def write_glb(self, path, name, extensions):
        doc = self.finish(name, extensions)
        doc["buffers"] = [{"byteLength": len(self.bin)}]
        js = dumps(doc).encode()
        js += b" " * (-len(js) % 4)
        body = struct.pack("<II", len(js), 0x4E4F534A) + js + struct.pack("<II", len(self.bin), 0x004E4942) + bytes(self.bin)
        with open(path, "wb") as f:
            f.write(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)


def dumps(doc):
    return json.dumps(doc, indent=1) + "\n"


def N(x):
    """A number for the glTF JSON, written exactly as the f32 it is read into."""
    return float(num(x))


def vec(v):
    return [N(c) for c in v]


def toml_vec(v):
    return "[" + ", ".join(num(c) for c in v) + "]"


GLASS = {"pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.0},
         "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1.0}, "KHR_materials_ior": {"ior": 1.5}}}


def diffuse(rgb):
    return {"pbrMetallicRoughness": {"baseColorFactor": vec(rgb) + [1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0}}


def write_twin(name, header, materials, emitter, shapes):
    """The TOML twin: the same scene in photonkit's format, meshes in OBJ files beside it."""
    d = os.path.join(OUT, "twins")
    os.makedirs(d, exist_ok=True)
    out = [f"# The TOML twin of ../{name}: written by tools/gltf-samples.py; `photonkit trace` gives",
           "# the same photons from either file (tests/suite/gltf.rs).", f'name = "{header}"', ""]
    for mname, body in sorted(materials.items()):
        out += [f"[materials.{mname}]"] + body + [""]
    out += ["[[emitters]]"] + emitter + [""]
    for sname, mname, mesh, translate in shapes:
        obj = f"{name}-{sname}.obj"
        with open(os.path.join(d, obj), "w") as f:
            f.write(mesh.obj())
        out += ["[[shapes]]", f'name = "{sname}"', 'kind = "obj"', f'file = "{obj}"', f'material = "{mname}"']
        if translate is not None:
            out.append(f"transform = {{ translate = {toml_vec(translate)} }}")
        out.append("")
    with open(os.path.join(d, f"{name}.toml"), "w") as f:
        f.write("\n".join(out))


def glass_sphere():
    g = Gltf()
    glass = g.material("glass", GLASS)
    floor_m = g.material("floor", diffuse((0.6, 0.6, 0.6)))
    floor = quad(-2.0, -2.0, 2.0, 2.0, 0.0)
    ball = uv_sphere(0.5, 48, 24)
    g.node({"name": "floor", "mesh": g.mesh("floor", floor, floor_m)})
    g.node({"name": "ball", "mesh": g.mesh("ball", ball, glass), "translation": vec((0, 0, 0.8))})
    lux = 10.0 * LUMENS_PER_WATT / (1.0 * 1.0)
    sun = g.light({"name": "sun", "type": "directional", "intensity": N(lux), "color": [1.0, 1.0, 1.0],
                   "extras": {"photonkit_beam_size": [1.0, 1.0]}})
    g.node({"name": "sun", "translation": vec((0, 0, 2)), "extensions": {"KHR_lights_punctual": {"light": sun}}})
    g.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": N(math.radians(35)), "aspectRatio": 1.0, "znear": 0.01}}]
    g.node({"name": "camera", "camera": 0, "translation": vec((0, -3, 2)),
            "rotation": [float(c) for c in look_at_quaternion((0, -3, 2), (0, 0, 0.4))]})
    g.write_gltf(os.path.join(OUT, "glass-sphere.gltf"), "glass sphere under a collimated beam",
                 ["KHR_lights_punctual", "KHR_materials_transmission", "KHR_materials_ior"], embed=False)
    power = f32(lux) * 1.0 / LUMENS_PER_WATT
    write_twin("glass-sphere", "glass sphere under a collimated beam",
               {"glass": ['kind = "dielectric"', "ior = 1.5"], "floor": ['kind = "diffuse"', "albedo = [0.6, 0.6, 0.6]"]},
               ['name = "sun"', 'kind = "collimated"', "center = [0.0, 0.0, 2.0]", "size = [1.0, 1.0]",
                "direction = [0.0, 0.0, -1.0]", f"power_w = {power!r}"],
               [("floor", "floor", floor, None), ("ball", "glass", ball, (0, 0, 0.8))])


COGNAC_GLASS = [
    (0.0, 0.0002), (0.035, 0.0002), (0.035, 0.003), (0.006, 0.006), (0.005, 0.045),
    (0.015, 0.052), (0.028, 0.060), (0.038, 0.072), (0.044, 0.087), (0.045, 0.100),
    (0.043, 0.115), (0.038, 0.130), (0.032, 0.145), (0.030, 0.155),
    (0.028, 0.155), (0.030, 0.145), (0.036, 0.130), (0.041, 0.115), (0.043, 0.100),
    (0.042, 0.087), (0.036, 0.073), (0.026, 0.062), (0.013, 0.055), (0.0, 0.053)]
COGNAC_LIQUID = [
    (0.0, 0.0535), (0.0128, 0.0555), (0.0257, 0.0625), (0.0355, 0.0735),
    (0.0406, 0.0847), (0.0387, 0.0843), (0.0367, 0.0846), (0.0348, 0.0854),
    (0.0329, 0.0858), (0.0309, 0.0853), (0.0290, 0.0844), (0.0271, 0.0841),
    (0.0251, 0.0848), (0.0232, 0.0857), (0.0213, 0.0859), (0.0193, 0.0850),
    (0.0174, 0.0841), (0.0155, 0.0842), (0.0135, 0.0851), (0.0116, 0.0860),
    (0.0097, 0.0858), (0.0077, 0.0847), (0.0058, 0.0839), (0.0039, 0.0843),
    (0.0019, 0.0855), (0.0, 0.0862)]


def cognac():
    g = Gltf()
    tint = (0.97, 0.85, 0.62)
    # KHR_materials_volume: attenuation colour c over distance d through thickness 2d keeps c²,
    # so each of a crossing's two refractions keeps c: the TOML tint.
    liquid = dict(GLASS, extensions={"KHR_materials_transmission": {"transmissionFactor": 1.0},
                                      "KHR_materials_ior": {"ior": N(1.36)},
                                      "KHR_materials_volume": {"attenuationColor": vec(tint), "attenuationDistance": N(0.05),
                                                               "thicknessFactor": N(0.1)}})
    m_cognac = g.material("cognac", liquid)
    m_glass = g.material("glass", GLASS)
    m_table = g.material("table", diffuse((0.7, 0.65, 0.6)))
    table = quad(-0.5, -0.5, 0.5, 0.5, 0.0)
    glass = revolution(COGNAC_GLASS, 64, 40.0)
    liquid_mesh = revolution(COGNAC_LIQUID, 64, 40.0)
    g.node({"name": "table", "mesh": g.mesh("table", table, m_table)})
    # The glass and its cognac under one node, each placed relative to it: the hierarchy's
    # translations add up to the TOML twin's (0.5 − 0.5 = 0 exactly).
    holder = g.node({"name": "glass of cognac", "translation": vec((0, 0, 0.5))})
    g.node({"name": "glass", "mesh": g.mesh("glass", glass, m_glass), "translation": vec((0, 0, -0.5))}, holder)
    g.node({"name": "cognac", "mesh": g.mesh("cognac", liquid_mesh, m_cognac), "translation": vec((0, 0, -0.5))}, holder)
    half = f32_to_radians(9.0)
    watts = 3.0
    cd = f32(watts * LUMENS_PER_WATT / (2.0 * math.pi * (1.0 - math.cos(half))))
    lamp = g.light({"name": "lamp", "type": "spot", "intensity": N(cd), "color": vec((1.0, 0.9, 0.75)),
                    "spot": {"innerConeAngle": 0.0, "outerConeAngle": N(half)}})
    # A matrix whose −z column is the TOML twin's direction as written (unnormalised), so both
    # files normalise the same three numbers.
    direction = (0.30, 0.0, -0.27)
    m = [0.0, 1.0, 0.0, 0.0,  -0.27, 0.0, -0.30, 0.0,  -0.30, 0.0, 0.27, 0.0,  -0.30, 0.0, 0.36, 1.0]
    g.node({"name": "lamp", "matrix": [N(x) for x in m], "extensions": {"KHR_lights_punctual": {"light": lamp}}})
    g.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": N(math.radians(38)), "aspectRatio": 1.0, "znear": 0.001}}]
    g.node({"name": "camera", "camera": 0, "translation": vec((-0.25, -0.40, 0.32)),
            "rotation": [float(c) for c in look_at_quaternion((-0.25, -0.40, 0.32), (0.08, 0.0, 0.04))]})
    g.write_glb(os.path.join(OUT, "cognac.glb"), "a cognac glass of agitated liquid under a lamp",
                ["KHR_lights_punctual", "KHR_materials_transmission", "KHR_materials_ior", "KHR_materials_volume"])
    power = cd * 2.0 * math.pi * (1.0 - math.cos(half)) / LUMENS_PER_WATT
    write_twin("cognac", "a cognac glass of agitated liquid under a lamp",
               {"table": ['kind = "diffuse"', "albedo = [0.7, 0.65, 0.6]"], "glass": ['kind = "dielectric"', "ior = 1.5"],
                "cognac": ['kind = "dielectric"', "ior = 1.36", f"tint = {toml_vec(tint)}"]},
               ['name = "lamp"', 'kind = "spot"', "position = [-0.3, 0.0, 0.36]", f"direction = {toml_vec(direction)}",
                "half_angle_deg = 9.0", f"power_w = {power!r}", "colour = [1.0, 0.9, 0.75]"],
               [("table", "table", table, None), ("glass", "glass", glass, None), ("cognac", "cognac", liquid_mesh, None)])


def reflector():
    g = Gltf()
    m_alu = g.material("aluminium", {"pbrMetallicRoughness": {"baseColorFactor": vec((0.9, 0.9, 0.9)) + [1.0],
                                                              "metallicFactor": 1.0, "roughnessFactor": 0.0}})
    m_floor = g.material("floor", diffuse((0.7, 0.7, 0.7)))
    m_glass = g.material("glass", GLASS)
    floor = quad(-1.5, -1.5, 1.5, 1.5, 0.0)
    # In the lamp's frame (1 m up): vertex at 0.2, focus at 0.1, the shield at 0.03–0.04.
    dish = paraboloid_down(0.1, 0.03, 0.25, 6, 24, 0.2)
    outline = [(0.26 * math.cos(2 * math.pi * k / 16), 0.26 * math.sin(2 * math.pi * k / 16)) for k in range(16)]
    shield = slab(outline, 0.03, 0.04)
    g.node({"name": "floor", "mesh": g.mesh("floor", floor, m_floor)})
    lamp = g.node({"name": "lamp", "translation": vec((0, 0, 1.0))})
    g.node({"name": "reflector", "mesh": g.mesh("reflector", dish, m_alu)}, lamp)
    g.node({"name": "shield", "mesh": g.mesh("shield", shield, m_glass)}, lamp)
    watts = 60.0
    cd = f32(watts * LUMENS_PER_WATT / (4.0 * math.pi))
    bulb = g.light({"name": "bulb", "type": "point", "intensity": N(cd), "color": vec((1.0, 0.85, 0.6))})
    g.node({"name": "bulb", "translation": vec((0, 0, 0.1)), "extensions": {"KHR_lights_punctual": {"light": bulb}}}, lamp)
    g.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": N(math.radians(45)), "aspectRatio": 1.0, "znear": 0.01}}]
    g.node({"name": "camera", "camera": 0, "translation": vec((0, -2.5, 1.5)),
            "rotation": [float(c) for c in look_at_quaternion((0, -2.5, 1.5), (0, 0, 0.3))]})
    g.write_gltf(os.path.join(OUT, "reflector.gltf"), "faceted reflector over a bulb behind a glass shield",
                 ["KHR_lights_punctual", "KHR_materials_transmission", "KHR_materials_ior"], embed=True)
    power = cd * 4.0 * math.pi / LUMENS_PER_WATT
    bulb_z = f32(f32(1.0) + f32(0.1))  # the lamp's translation plus the bulb's, in f32
    write_twin("reflector", "faceted reflector over a bulb behind a glass shield",
               {"floor": ['kind = "diffuse"', "albedo = [0.7, 0.7, 0.7]"],
                "aluminium": ['kind = "mirror"', "reflectance = [0.9, 0.9, 0.9]"], "glass": ['kind = "dielectric"', "ior = 1.5"]},
               ['name = "bulb"', 'kind = "point"', f"position = [0.0, 0.0, {bulb_z!r}]", f"power_w = {power!r}",
                "colour = [1.0, 0.85, 0.6]"],
               [("floor", "floor", floor, None), ("reflector", "aluminium", dish, (0, 0, 1.0)),
                ("shield", "glass", shield, (0, 0, 1.0))])


if __name__ == "__main__":
    os.makedirs(OUT, exist_ok=True)
    glass_sphere()
    cognac()
    reflector()
