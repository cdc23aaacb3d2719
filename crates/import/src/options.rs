//! [`ImportOptions`] and name patterns.

use crate::error::ImportError;

/// Options of [`import`](crate::import): wood/leaf overrides, limits and the
/// skeleton extraction's resolution.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct ImportOptions {
    /// Primitives whose material name or mesh name matches one of these
    /// patterns are leaves, whatever their material says (default empty).
    /// See [`name_matches`] for the pattern syntax.
    pub leaf_materials: Vec<String>,
    /// Primitives whose material name or mesh name matches one of these
    /// patterns are wood (default empty). Wood patterns win over leaf
    /// patterns.
    pub wood_materials: Vec<String>,
    /// Rebuild the tree from the meshes even when the GLB carries a
    /// treemorph tree (default `false`: an embedded tree is used as is).
    pub ignore_embedded_tree: bool,
    /// Largest input accepted, bytes (default 512 MiB).
    pub max_file_bytes: usize,
    /// Largest JSON document (the `.gltf` file or the GLB's JSON chunk),
    /// bytes (default 64 MiB). JSON costs far more memory than binary data.
    pub max_json_bytes: usize,
    /// Most vertices read over all primitives and instances (default
    /// 2,000,000: four times a dense 10,000-branch tree).
    pub max_vertices: usize,
    /// Most triangles read over all primitives and instances (default
    /// 4,000,000).
    pub max_triangles: usize,
    /// Most leaves in the result (default 500,000).
    pub max_leaves: usize,
    /// Most skeleton nodes in the result (default 1,000,000).
    pub max_nodes: usize,
    /// Longest side of a texture image, pixels (default 4,096). Larger
    /// images are refused before they are decoded.
    pub max_texture_side: u32,
    /// Smallest vertex budget of the simplified proxy that mesh contraction
    /// runs on (default 40,000; the budget is a third of the mesh's
    /// vertices, up to 150,000, when that is more). Welded meshes with
    /// more vertices are clustered first (see the crate docs); larger
    /// budgets are slower and follow thin twigs more closely.
    pub contraction_vertices: usize,
    /// Laplacian contraction iterations (default 6, at most 32).
    pub contraction_iterations: u32,
}

impl Default for ImportOptions {
    fn default() -> ImportOptions {
        ImportOptions {
            leaf_materials: Vec::new(),
            wood_materials: Vec::new(),
            ignore_embedded_tree: false,
            max_file_bytes: 512 << 20,
            max_json_bytes: 64 << 20,
            max_vertices: 2_000_000,
            max_triangles: 4_000_000,
            max_leaves: 500_000,
            max_nodes: 1_000_000,
            max_texture_side: 4096,
            contraction_vertices: 40_000,
            contraction_iterations: 6,
        }
    }
}

impl ImportOptions {
    /// These options with [`ImportOptions::leaf_materials`] set.
    #[must_use]
    pub fn with_leaf_materials<S: Into<String>>(
        mut self,
        patterns: impl IntoIterator<Item = S>,
    ) -> ImportOptions {
        self.leaf_materials = patterns.into_iter().map(Into::into).collect();
        self
    }

    /// These options with [`ImportOptions::wood_materials`] set.
    #[must_use]
    pub fn with_wood_materials<S: Into<String>>(
        mut self,
        patterns: impl IntoIterator<Item = S>,
    ) -> ImportOptions {
        self.wood_materials = patterns.into_iter().map(Into::into).collect();
        self
    }

    /// These options with [`ImportOptions::ignore_embedded_tree`] set.
    #[must_use]
    pub fn with_ignore_embedded_tree(mut self, ignore: bool) -> ImportOptions {
        self.ignore_embedded_tree = ignore;
        self
    }

    pub(crate) fn check(&self) -> Result<(), ImportError> {
        let bad = |m: String| Err(ImportError::InvalidOptions(m));
        if self.contraction_vertices < 100 {
            return bad(format!(
                "contraction_vertices must be at least 100; got {}",
                self.contraction_vertices
            ));
        }
        if !(1..=32).contains(&self.contraction_iterations) {
            return bad(format!(
                "contraction_iterations must be within 1..=32; got {}",
                self.contraction_iterations
            ));
        }
        if self.max_texture_side == 0 {
            return bad("max_texture_side must be positive".into());
        }
        Ok(())
    }

    pub(crate) fn limits(&self) -> treemorph_tree::Limits {
        let mut limits = treemorph_tree::Limits::with_sizes(self.max_nodes, self.max_leaves);
        limits.max_texture_side = self.max_texture_side;
        limits
    }
}

/// Whether `name` matches `pattern`, ignoring ASCII case.
///
/// A pattern with `*` (any run of characters) or `?` (one character) is a
/// glob matched against the whole name (`"lea*"` matches `"Leaves_01"`);
/// a pattern without them matches anywhere in the name (`"leaf"` matches
/// `"OakLeaf_Mat"`). The empty pattern matches nothing.
pub fn name_matches(pattern: &str, name: &str) -> bool {
    if pattern.is_empty() {
        return false;
    }
    let p: Vec<char> = pattern.to_lowercase().chars().collect();
    let n: Vec<char> = name.to_lowercase().chars().collect();
    if !p.iter().any(|&c| c == '*' || c == '?') {
        let p: String = p.into_iter().collect();
        let n: String = n.into_iter().collect();
        return n.contains(&p);
    }
    // Iterative glob with single backtracking point: linear in practice.
    let (mut i, mut j) = (0usize, 0usize);
    let mut star: Option<(usize, usize)> = None;
    while j < n.len() {
        if i < p.len() && (p[i] == '?' || p[i] == n[j]) {
            i += 1;
            j += 1;
        } else if i < p.len() && p[i] == '*' {
            star = Some((i, j));
            i += 1;
        } else if let Some((si, sj)) = star {
            i = si + 1;
            j = sj + 1;
            star = Some((si, sj + 1));
        } else {
            return false;
        }
    }
    while i < p.len() && p[i] == '*' {
        i += 1;
    }
    i == p.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn substring_and_glob_patterns() {
        assert!(name_matches("leaf", "OakLeaf_Mat"));
        assert!(!name_matches("leaf", "Bark"));
        assert!(name_matches("lea*", "Leaves_01"));
        assert!(!name_matches("lea*", "OakLeaf"));
        assert!(name_matches("*bark?", "TreeBark1"));
        assert!(!name_matches("*bark?", "TreeBark"));
        assert!(name_matches("*", ""));
        assert!(!name_matches("", "anything"));
        assert!(name_matches("a*b*c", "aXXbYYc"));
        assert!(!name_matches("a*b*c", "aXXbYY"));
    }

    #[test]
    fn options_are_checked() {
        assert!(ImportOptions::default().check().is_ok());
        let o = ImportOptions {
            contraction_iterations: 0,
            ..ImportOptions::default()
        };
        assert_eq!(o.check().unwrap_err().code(), "invalid_options");
    }
}
