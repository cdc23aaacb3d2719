//! Reading back the GLBs this crate writes, for tests: accessors of every
//! component type this crate uses, through `EXT_meshopt_compression` too
//! (decoded with meshoptimizer's decoders).

use glam::{Vec2, Vec3};
use serde_json::Value;

use crate::bench::Sway;
use crate::gl::{BYTE, FLOAT, SHORT, UNSIGNED_BYTE, UNSIGNED_INT, UNSIGNED_SHORT};
use crate::glb::Glb;

/// A parsed GLB: its JSON and its BIN chunk.
pub(crate) struct Parsed {
    pub(crate) json: Value,
    pub(crate) bin: Vec<u8>,
}

impl Parsed {
    pub(crate) fn new(glb: &[u8]) -> Parsed {
        let container = Glb::from_slice(glb).unwrap();
        Parsed {
            json: serde_json::from_slice(container.json).unwrap(),
            bin: container.bin.unwrap_or_default().to_vec(),
        }
    }

    /// The plain bytes of a buffer view, decompressing meshopt views.
    pub(crate) fn view(&self, index: usize) -> Vec<u8> {
        let view = &self.json["bufferViews"][index];
        if let Some(ext) = view["extensions"].get("EXT_meshopt_compression") {
            let offset = ext["byteOffset"].as_u64().unwrap_or(0) as usize;
            let len = ext["byteLength"].as_u64().unwrap() as usize;
            let stride = ext["byteStride"].as_u64().unwrap() as usize;
            let count = ext["count"].as_u64().unwrap() as usize;
            let data = &self.bin[offset..offset + len];
            return match ext["mode"].as_str().unwrap() {
                "ATTRIBUTES" => match stride {
                    4 => meshopt::decode_vertex_buffer::<[u8; 4]>(data, count)
                        .unwrap()
                        .concat(),
                    8 => meshopt::decode_vertex_buffer::<[u8; 8]>(data, count)
                        .unwrap()
                        .concat(),
                    12 => meshopt::decode_vertex_buffer::<[u8; 12]>(data, count)
                        .unwrap()
                        .concat(),
                    s => panic!("stride {s}"),
                },
                "TRIANGLES" => match stride {
                    2 => meshopt::decode_index_buffer::<u16>(data, count)
                        .unwrap()
                        .iter()
                        .flat_map(|i| i.to_le_bytes())
                        .collect(),
                    _ => meshopt::decode_index_buffer::<u32>(data, count)
                        .unwrap()
                        .iter()
                        .flat_map(|i| i.to_le_bytes())
                        .collect(),
                },
                m => panic!("mode {m}"),
            };
        }
        assert_eq!(view["buffer"], 0);
        let offset = view["byteOffset"].as_u64().unwrap_or(0) as usize;
        let len = view["byteLength"].as_u64().unwrap() as usize;
        self.bin[offset..offset + len].to_vec()
    }

    /// An accessor's components as floats (normalised integers mapped to
    /// [-1, 1] as glTF specifies), `n` per element.
    pub(crate) fn floats(&self, accessor: usize) -> (Vec<f32>, usize) {
        let a = &self.json["accessors"][accessor];
        let n = match a["type"].as_str().unwrap() {
            "SCALAR" => 1,
            "VEC2" => 2,
            "VEC3" => 3,
            "VEC4" => 4,
            "MAT4" => 16,
            t => panic!("type {t}"),
        };
        let count = a["count"].as_u64().unwrap() as usize;
        let Some(view_index) = a["bufferView"].as_u64() else {
            // No buffer view: all zeros.
            return (vec![0.0; count * n], n);
        };
        let view_index = view_index as usize;
        let bytes = self.view(view_index);
        let view = &self.json["bufferViews"][view_index];
        let component = a["componentType"].as_u64().unwrap() as u32;
        let size = match component {
            BYTE | UNSIGNED_BYTE => 1,
            SHORT | UNSIGNED_SHORT => 2,
            _ => 4,
        };
        let stride = view["byteStride"].as_u64().map_or(n * size, |s| s as usize);
        let offset = a["byteOffset"].as_u64().unwrap_or(0) as usize;
        let normalized = a["normalized"].as_bool().unwrap_or(false);
        let mut out = Vec::with_capacity(count * n);
        for i in 0..count {
            for c in 0..n {
                let at = offset + i * stride + c * size;
                let b = &bytes[at..at + size];
                let v = match component {
                    FLOAT => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                    UNSIGNED_INT => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
                    UNSIGNED_SHORT => {
                        let v = f32::from(u16::from_le_bytes([b[0], b[1]]));
                        if normalized { v / 65_535.0 } else { v }
                    }
                    SHORT => {
                        let v = f32::from(i16::from_le_bytes([b[0], b[1]]));
                        if normalized {
                            (v / 32_767.0).max(-1.0)
                        } else {
                            v
                        }
                    }
                    BYTE => {
                        let v = f32::from(b[0] as i8);
                        if normalized { (v / 127.0).max(-1.0) } else { v }
                    }
                    UNSIGNED_BYTE => f32::from(b[0]),
                    c => panic!("component {c}"),
                };
                out.push(v);
            }
        }
        (out, n)
    }

    pub(crate) fn vec3s(&self, accessor: usize) -> Vec<Vec3> {
        let (f, n) = self.floats(accessor);
        assert_eq!(n, 3);
        f.chunks_exact(3).map(Vec3::from_slice).collect()
    }

    pub(crate) fn vec2s(&self, accessor: usize) -> Vec<Vec2> {
        let (f, n) = self.floats(accessor);
        assert_eq!(n, 2);
        f.chunks_exact(2).map(Vec2::from_slice).collect()
    }

    pub(crate) fn indices(&self, accessor: usize) -> Vec<u32> {
        self.floats(accessor).0.iter().map(|&v| v as u32).collect()
    }

    /// The mesh of the node named `name`.
    pub(crate) fn node(&self, name: &str) -> &Value {
        self.json["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .find(|n| n["name"] == name)
            .unwrap()
    }

    pub(crate) fn mesh_of(&self, name: &str) -> &Value {
        let m = self.node(name)["mesh"].as_u64().unwrap() as usize;
        &self.json["meshes"][m]
    }

    /// The weights the animation's sampler gives at keyframe `k`.
    pub(crate) fn keyframe_weights(&self, k: usize) -> Vec<f32> {
        let sampler = &self.json["animations"][0]["samplers"][0];
        let (times, _) = self.floats(sampler["input"].as_u64().unwrap() as usize);
        let (weights, _) = self.floats(sampler["output"].as_u64().unwrap() as usize);
        let n = weights.len() / times.len();
        weights[k * n..(k + 1) * n].to_vec()
    }

    /// The morphed attribute (`POSITION` or `NORMAL`) of the node's mesh.
    fn morphed_attribute(&self, name: &str, attribute: &str, weights: &[f32]) -> Vec<Vec3> {
        let mesh = self.mesh_of(name);
        let prim = &mesh["primitives"][0];
        let mut p = self.vec3s(prim["attributes"][attribute].as_u64().unwrap() as usize);
        for (k, &w) in weights.iter().enumerate() {
            if w == 0.0 {
                continue;
            }
            let accessor = prim["targets"][k][attribute].as_u64().unwrap() as usize;
            if self.json["accessors"][accessor].get("bufferView").is_none() {
                continue;
            }
            let t = self.vec3s(accessor);
            for (p, d) in p.iter_mut().zip(t) {
                *p += d * w;
            }
        }
        p
    }

    /// Positions of the node's mesh morphed by `weights`, in world space
    /// (the node's translation and uniform scale applied).
    pub(crate) fn morphed(&self, name: &str, weights: &[f32]) -> Vec<Vec3> {
        let node = self.node(name);
        let p = self.morphed_attribute(name, "POSITION", weights);
        let scale = node["scale"]
            .as_array()
            .map_or(1.0, |s| s[0].as_f64().unwrap() as f32);
        let translation = node["translation"].as_array().map_or(Vec3::ZERO, |t| {
            Vec3::new(
                t[0].as_f64().unwrap() as f32,
                t[1].as_f64().unwrap() as f32,
                t[2].as_f64().unwrap() as f32,
            )
        });
        p.iter().map(|&v| translation + v * scale).collect()
    }

    /// What a player shows of the skinned node `name` (first primitive,
    /// one joint per vertex) at the time of animation key `k` (the first
    /// sampler's keys, one per sample): the joints' translation, rotation and scale
    /// at that key composed down the node hierarchy, times their inverse
    /// bind matrices, applied to the positions morphed by the node's
    /// weights at that key (or by none). The `hidden` target of a swapping
    /// node is left out: it only hides the node, and this is the geometry
    /// it shows when drawn.
    pub(crate) fn skinned(&self, name: &str, k: usize, with_targets: bool) -> Vec<Vec3> {
        let nodes = self.json["nodes"].as_array().unwrap();
        let index = |n: &Value| nodes.iter().position(|m| m == n).unwrap();
        let animation = &self.json["animations"][0];
        let input = |sampler: &Value| self.floats(sampler["input"].as_u64().unwrap() as usize).0;
        // Key `k`'s time; a `hidden` weights sampler has extra keys just
        // before its swaps, so keys are found by time.
        let time = input(&animation["samplers"][0])[k];
        let at = |node: usize, path: &str, n: usize| -> Option<Vec<f32>> {
            let channel = animation["channels"]
                .as_array()?
                .iter()
                .find(|c| c["target"]["node"] == node && c["target"]["path"] == path)?;
            let sampler = &animation["samplers"][channel["sampler"].as_u64()? as usize];
            let key = input(sampler).iter().position(|&t| t == time)?;
            let (values, _) = self.floats(sampler["output"].as_u64()? as usize);
            Some(values[key * n..(key + 1) * n].to_vec())
        };
        let mut parent = vec![None; nodes.len()];
        for (i, n) in nodes.iter().enumerate() {
            for c in n["children"].as_array().into_iter().flatten() {
                parent[c.as_u64().unwrap() as usize] = Some(i);
            }
        }
        let local = |i: usize| {
            let get = |path: &str, n: usize, default: &[f32]| {
                at(i, path, n).unwrap_or_else(|| {
                    nodes[i][path].as_array().map_or(default.to_vec(), |v| {
                        v.iter().map(|x| x.as_f64().unwrap() as f32).collect()
                    })
                })
            };
            let t = get("translation", 3, &[0.0; 3]);
            let r = get("rotation", 4, &[0.0, 0.0, 0.0, 1.0]);
            let s = get("scale", 3, &[1.0; 3]);
            glam::Mat4::from_scale_rotation_translation(
                Vec3::from_slice(&s),
                glam::Quat::from_slice(&r),
                Vec3::from_slice(&t),
            )
        };
        let world = |mut i: usize| {
            let mut m = local(i);
            while let Some(p) = parent[i] {
                m = local(p) * m;
                i = p;
            }
            m
        };
        let skin = &self.json["skins"][0];
        let joints: Vec<usize> = skin["joints"]
            .as_array()
            .unwrap()
            .iter()
            .map(|j| j.as_u64().unwrap() as usize)
            .collect();
        let (ibm, _) = self.floats(skin["inverseBindMatrices"].as_u64().unwrap() as usize);
        let skinning: Vec<glam::Mat4> = joints
            .iter()
            .enumerate()
            .map(|(j, &node)| world(node) * glam::Mat4::from_cols_slice(&ibm[16 * j..16 * (j + 1)]))
            .collect();
        let node = index(self.node(name));
        let targets = self.mesh_of(name)["primitives"][0]["targets"]
            .as_array()
            .map_or(0, Vec::len);
        let mut weights = match with_targets {
            true => at(node, "weights", targets).unwrap_or_default(),
            false => Vec::new(),
        };
        let names = self.mesh_of(name)["extras"]["targetNames"].as_array();
        if let Some(hidden) = names.and_then(|n| n.iter().position(|t| t == "hidden"))
            && let Some(w) = weights.get_mut(hidden)
        {
            *w = 0.0;
        }
        let prim = &self.mesh_of(name)["primitives"][0];
        let (vertex_joints, _) =
            self.floats(prim["attributes"]["JOINTS_0"].as_u64().unwrap() as usize);
        self.morphed_attribute(name, "POSITION", &weights)
            .iter()
            .enumerate()
            .map(|(v, &p)| skinning[vertex_joints[4 * v] as usize].transform_point3(p))
            .collect()
    }

    /// Unit normals of the node's mesh morphed by `weights`.
    pub(crate) fn morphed_normals(&self, name: &str, weights: &[f32]) -> Vec<Vec3> {
        self.morphed_attribute(name, "NORMAL", weights)
            .iter()
            .map(|n| n.normalize_or_zero())
            .collect()
    }
}

/// Triangles with each rotated to start at its smallest index (meshopt's
/// index codec may rotate a triangle's vertices; winding is kept).
pub(crate) fn canonical_triangles(indices: &[u32]) -> Vec<[u32; 3]> {
    indices
        .chunks_exact(3)
        .map(|t| {
            let r = (0..3).min_by_key(|&i| t[i]).unwrap();
            [t[r], t[(r + 1) % 3], t[(r + 2) % 3]]
        })
        .collect()
}

/// Writes `glb` and `expected` (the `EXPECTED.json` of
/// `tools/render/check-animated.mjs`) as `target/threejs-check/NAME.glb`
/// and `.json`, runs the checker on them and fails the test when three.js
/// disagrees.
pub(crate) fn check_with_threejs(name: &str, glb: &[u8], expected: &Value) {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let tool = root.join("tools/render");
    assert!(
        tool.join("node_modules/three").exists(),
        "run `npm ci --prefix tools/render` first"
    );
    let dir = root.join("target/threejs-check");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join(format!("{name}.glb"));
    let expected_file = dir.join(format!("{name}.json"));
    std::fs::write(&file, glb).unwrap();
    std::fs::write(&expected_file, serde_json::to_vec(expected).unwrap()).unwrap();
    let output = std::process::Command::new("node")
        .arg(tool.join("check-animated.mjs"))
        .arg(&file)
        .arg(&expected_file)
        .output()
        .expect("node runs");
    println!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(
        output.status.success(),
        "three.js disagrees about {}",
        file.display()
    );
}

/// The animated GLB tests' sequence: a 300-branch maple swaying over
/// `frames` frames while its leaves change material.
pub(crate) fn maple_sway(frames: usize) -> Sway {
    let options = treemorph_generate::GenerateOptions::new(treemorph_generate::Preset::Maple, 3);
    Sway::new(
        &treemorph_generate::generate(&options.with_size(300)).unwrap(),
        frames,
    )
}
