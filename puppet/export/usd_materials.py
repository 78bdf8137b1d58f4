"""glTF materials as USD UsdPreviewSurface materials, their images as texture files.

One ``UsdShade.Material`` per glTF material under ``<root>/Materials``, its surface a
``UsdPreviewSurface`` (metallic workflow):
  diffuseColor   baseColorFactor, or a UsdUVTexture of baseColorTexture (sRGB) scaled by it;
  opacity        baseColorFactor's alpha (or the texture's a) when alphaMode is BLEND or MASK
                 (MASK: opacityThreshold = alphaCutoff);
  metallic, roughness  the factors, or metallicRoughnessTexture's b and g scaled by them (raw);
  normal         normalTexture (raw, mapped from [0, 1] to [-1, 1], xy times its scale);
  occlusion      occlusionTexture's r; emissiveColor: emissiveFactor, or emissiveTexture times it.
Each texture reads the mesh's primvar ``st`` (TEXCOORD_0) or ``st<k>`` (TEXCOORD_k) through a
UsdPrimvarReader_float2, with the glTF sampler's wrap modes. Image k is written once as the file
``<k>_<name>.png`` (or .jpg) in the textures folder; the shaders name it relative to the layer.
KHR texture transforms and other material extensions are not carried.
"""

from __future__ import annotations

import os
from pathlib import Path

from puppet.export.names import safe_name, safe_names

WRAP = {33071: "clamp", 33648: "mirror", 10497: "repeat"}
EXTENSIONS = {"image/png": ".png", "image/jpeg": ".jpg"}
IMAGE_MAGICS = (b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff")
"""How a PNG and a JPEG begin: an image file that does not is left out, with a warning."""


def primvar_name(texcoord: int) -> str:
    """The mesh primvar of glTF TEXCOORD_<texcoord>: 'st', 'st1', 'st2', ..."""
    return "st" if texcoord == 0 else f"st{texcoord}"


def write_textures(scene, folder: Path, inputs=()) -> tuple[dict[int, Path], list[str]]:
    """Write the scene's images into ``folder`` (made if missing): ({image index: file}, warnings
    naming each image that cannot be read). inputs: files no texture may overwrite."""
    from puppet.atomic import atomic_output, check_folder_output

    files, warnings = {}, []
    for i, image in enumerate(scene.images):
        if image is None:
            continue
        data, warning = image.read()
        if warning:
            warnings.append(warning)
            continue
        if not data.startswith(IMAGE_MAGICS):
            where = image.path if image.path is not None else f"image {i} of the character"
            warnings.append(f"{where}: not a PNG or JPEG image ({len(data)} bytes starting "
                            f"{data[:8]!r}): its textures are left out (the materials are "
                            "exported plain)")
            continue
        check_folder_output(folder, what="textures folder")
        folder.mkdir(parents=True, exist_ok=True)
        target = folder / f"{i}_{safe_name(image.name or 'image')}{EXTENSIONS.get(image.mime_type, '.png')}"
        with atomic_output(target, kind="png", inputs=inputs, force=True, what="texture") as temporary:
            temporary.write_bytes(data)
        files[i] = target
    return files, warnings


def write_materials(stage, root: str, scene, files: dict[int, Path], layer_folder: Path) -> list:
    """Define every material of ``scene`` under ``<root>/Materials``; returns the
    UsdShade.Material of each glTF material index. files: {image index: texture file};
    layer_folder: the folder of the layer (texture paths are written relative to it)."""
    from pxr import Gf, Sdf, UsdGeom, UsdShade

    names, _ = safe_names([m.get("name") or f"material{k}" for k, m in enumerate(scene.materials)])
    if scene.materials:
        UsdGeom.Scope.Define(stage, f"{root}/Materials")
    out = []
    for k, m in enumerate(scene.materials):
        path = f"{root}/Materials/{names[k]}"
        material = UsdShade.Material.Define(stage, path)
        surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
        surface.CreateIdAttr("UsdPreviewSurface")
        surface.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(0)
        material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
        readers: dict[int, object] = {}

        def texture(info: dict, label: str, scale, colour: bool, bias=None):
            """A UsdUVTexture of a glTF textureInfo, or None when its image was not written."""
            t = info.get("index")
            if not isinstance(t, int) or not 0 <= t < len(scene.textures):
                return None
            tex = scene.textures[t]
            image = tex.get("source")
            if image not in files:
                return None
            coord = int(info.get("texCoord", 0) or 0)
            if coord not in readers:
                reader = UsdShade.Shader.Define(stage, f"{path}/{primvar_name(coord)}Reader")
                reader.CreateIdAttr("UsdPrimvarReader_float2")
                reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set(primvar_name(coord))
                readers[coord] = reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
            shader = UsdShade.Shader.Define(stage, f"{path}/{label}")
            shader.CreateIdAttr("UsdUVTexture")
            relative = os.path.relpath(files[image], layer_folder).replace(os.sep, "/")
            shader.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(f"./{relative}"))
            shader.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(readers[coord])
            shader.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(
                "sRGB" if colour else "raw")
            sampler = tex.get("sampler")
            if isinstance(sampler, int) and 0 <= sampler < len(scene.samplers):
                s = scene.samplers[sampler]
                for axis in ("wrapS", "wrapT"):
                    wrap = WRAP.get(s.get(axis, 10497), "repeat")
                    shader.CreateInput(axis, Sdf.ValueTypeNames.Token).Set(wrap)
            else:
                for axis in ("wrapS", "wrapT"):
                    shader.CreateInput(axis, Sdf.ValueTypeNames.Token).Set("repeat")
            shader.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*map(float, scale)))
            if bias is not None:
                shader.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*map(float, bias)))
            return shader

        def connect(name, kind, shader, output, out_kind):
            surface.CreateInput(name, kind).ConnectToSource(shader.CreateOutput(output, out_kind))

        pbr = m.get("pbrMetallicRoughness") or {}
        base = [float(x) for x in pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])]
        mode = m.get("alphaMode", "OPAQUE")
        colour = texture(pbr.get("baseColorTexture") or {}, "BaseColor", base, True)
        C3, F1 = Sdf.ValueTypeNames.Color3f, Sdf.ValueTypeNames.Float
        if colour is not None:
            connect("diffuseColor", C3, colour, "rgb", Sdf.ValueTypeNames.Float3)
        else:
            surface.CreateInput("diffuseColor", C3).Set(Gf.Vec3f(*base[:3]))
        if mode in ("BLEND", "MASK"):
            if colour is not None:
                connect("opacity", F1, colour, "a", F1)
            else:
                surface.CreateInput("opacity", F1).Set(base[3])
            if mode == "MASK":
                surface.CreateInput("opacityThreshold", F1).Set(float(m.get("alphaCutoff", 0.5)))
        metal = float(pbr.get("metallicFactor", 1.0))
        rough = float(pbr.get("roughnessFactor", 1.0))
        mr = texture(pbr.get("metallicRoughnessTexture") or {}, "MetallicRoughness",
                     (1.0, rough, metal, 1.0), False)
        if mr is not None:
            connect("metallic", F1, mr, "b", F1)
            connect("roughness", F1, mr, "g", F1)
        else:
            surface.CreateInput("metallic", F1).Set(metal)
            surface.CreateInput("roughness", F1).Set(rough)
        normal_info = m.get("normalTexture") or {}
        s = float(normal_info.get("scale", 1.0))
        normal = texture(normal_info, "Normal", (2 * s, 2 * s, 2.0, 1.0), False, bias=(-s, -s, -1.0, 0.0))
        if normal is not None:
            connect("normal", Sdf.ValueTypeNames.Normal3f, normal, "rgb", Sdf.ValueTypeNames.Float3)
        occlusion = texture(m.get("occlusionTexture") or {}, "Occlusion", (1.0, 1.0, 1.0, 1.0), False)
        if occlusion is not None:
            connect("occlusion", F1, occlusion, "r", F1)
        emissive = [float(x) for x in m.get("emissiveFactor", [0.0, 0.0, 0.0])]
        glow = texture(m.get("emissiveTexture") or {}, "Emissive", (*emissive, 1.0), True)
        if glow is not None:
            connect("emissiveColor", C3, glow, "rgb", Sdf.ValueTypeNames.Float3)
        elif any(emissive):
            surface.CreateInput("emissiveColor", C3).Set(Gf.Vec3f(*emissive))
        out.append(material)
    return out
