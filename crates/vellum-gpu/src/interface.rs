//! Checks that a `#[repr(C)]` Rust struct and its GLSL twin in glsl/common/ agree: same members in
//! the same order, same offsets under std430 rules, same rounded size. Used by unit tests through
//! `assert_glsl_layout!`; the GLSL file is the single definition the shaders include.

/// (size, alignment) of a GLSL type under std430, with `count` for arrays.
#[cfg(any(test, feature = "layout-tests"))]
fn std430(ty: &str) -> Option<(usize, usize)> {
    Some(match ty {
        "int" | "uint" | "float" | "bool" => (4, 4),
        "ivec2" | "uvec2" | "vec2" => (8, 8),
        "ivec3" | "uvec3" | "vec3" => (12, 16),
        "ivec4" | "uvec4" | "vec4" => (16, 16),
        "mat4" => (64, 16),
        "mat3x4" => (48, 16),
        _ => return None,
    })
}

/// The members of `struct block { ... };` in `src`: (type, name, array count).
#[cfg(any(test, feature = "layout-tests"))]
fn members(src: &str, block: &str) -> Vec<(String, String, usize)> {
    let start = src
        .find(&format!("struct {block} {{"))
        .unwrap_or_else(|| panic!("struct {block} not found"));
    let body = &src[start..];
    let body = &body[body.find('{').expect("brace") + 1..body.find("};").expect("end of struct")];
    body.lines()
        .map(|l| l.split("//").next().unwrap_or("").trim())
        .filter(|l| !l.is_empty())
        .flat_map(|l| {
            l.split(';')
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .map(String::from)
                .collect::<Vec<_>>()
        })
        .map(|decl| {
            let mut parts = decl.split_whitespace();
            let ty = parts.next().expect("type").to_string();
            let name = parts.next().expect("name").to_string();
            match name.find('[') {
                Some(i) => {
                    let n = name[i + 1..name.len() - 1].parse().expect("array count");
                    (ty, name[..i].to_string(), n)
                }
                None => (ty, name, 1),
            }
        })
        .collect()
}

/// Panics unless `rust` (field name, offset) and `rust_size` match struct `block` of
/// glsl/common/`file` under std430.
#[cfg(any(test, feature = "layout-tests"))]
pub fn check_layout(file: &str, block: &str, rust: &[(&str, usize)], rust_size: usize) {
    let path = format!("{}/common/{file}", crate::GLSL_DIR);
    let src = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let glsl = members(&src, block);
    let names: Vec<&str> = glsl.iter().map(|(_, n, _)| n.as_str()).collect();
    let rust_names: Vec<&str> = rust.iter().map(|(n, _)| *n).collect();
    assert_eq!(
        names, rust_names,
        "{block}: member names or order differ between GLSL and Rust"
    );
    let mut offset = 0usize;
    let mut max_align = 4usize;
    for ((ty, name, count), (_, rust_offset)) in glsl.iter().zip(rust) {
        let (size, align) = std430(ty)
            .unwrap_or_else(|| panic!("{block}.{name}: type {ty} unknown to the layout check"));
        // std430: array elements of scalars/vectors keep their own alignment and size (vec3 arrays excepted).
        let (size, align) = if *count > 1 {
            (size.max(align) * count, align)
        } else {
            (size, align)
        };
        offset = offset.next_multiple_of(align);
        max_align = max_align.max(align);
        assert_eq!(
            offset, *rust_offset,
            "{block}.{name}: GLSL offset {offset} but Rust offset {rust_offset}"
        );
        offset += size;
    }
    let size = offset.next_multiple_of(max_align);
    assert_eq!(
        size, rust_size,
        "{block}: GLSL std430 size {size} but Rust size {rust_size}"
    );
}

/// `assert_glsl_layout!(RustType, "file.glsl", "GlslStruct", [field, ...])`, for the unit tests
/// of this crate and, through the `layout-tests` feature, of the crates above.
#[cfg(any(test, feature = "layout-tests"))]
#[macro_export]
macro_rules! assert_glsl_layout {
    ($ty:ty, $file:expr, $block:expr, [$($field:ident),* $(,)?]) => {{
        let rust = [$((stringify!($field), std::mem::offset_of!($ty, $field))),*];
        $crate::interface::check_layout($file, $block, &rust, std::mem::size_of::<$ty>());
    }};
}
#[cfg(any(test, feature = "layout-tests"))]
pub use crate::assert_glsl_layout;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_members_and_arrays() {
        let m = members("struct S {\n  ivec3 a; // c\n  int b[3];\n};", "S");
        assert_eq!(
            m,
            vec![
                ("ivec3".into(), "a".into(), 1),
                ("int".into(), "b".into(), 3)
            ]
        );
    }
}
