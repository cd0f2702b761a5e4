//! FM5, the feature map (paper §4): a tree of groups and features that records which private
//! interval of the feature volume holds which feature, saved as JSON beside the feature volume.
//!
//! JSON form (version 1):
//!
//! ```json
//! {
//!   "version": 1,
//!   "volume": "feature.nrrd",
//!   "context_range": [0.0, 255.0],
//!   "nodes": [
//!     {"kind": "group", "label": "bones", "description": "", "children": [
//!       {"kind": "feature", "label": "skull", "description": "seg3d mask",
//!        "interval": [268.0, 523.0], "color": [0.95, 0.85, 0.6]}
//!     ]}
//!   ]
//! }
//! ```
//!
//! `context_range` is the data range before the first migration, the part of the histogram that
//! holds unmigrated data; transfer functions show it as context. Intervals are in the feature
//! volume's data units, colours straight linear RGB in [0, 1] like transfer functions. Feature
//! labels are unique in a map, so a feature can be named on the command line.

use std::fmt;
use std::path::Path;

use serde::{Deserialize, Serialize};

use vellum_error::{Error, Result};

/// The JSON format version this code reads and writes.
pub(crate) const FEATURE_MAP_VERSION: u32 = 1;

/// Default colours, given to features in the order they are added (bone, red, blue, green,
/// orange, violet, then round again).
pub const PALETTE: [[f32; 3]; 6] = [
    [0.95, 0.85, 0.60],
    [0.90, 0.25, 0.20],
    [0.20, 0.55, 0.95],
    [0.30, 0.80, 0.35],
    [0.95, 0.55, 0.15],
    [0.70, 0.35, 0.85],
];

/// One migrated feature.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Feature {
    /// Short name, unique in the map.
    pub label: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// The private interval [lo, hi] in the feature volume's data units (eq. 2).
    pub interval: [f64; 2],
    /// Default colour, straight linear RGB in [0, 1].
    pub color: [f32; 3],
    /// The ROI's range before migration (ROI_low, ROI_high), for reference.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source_range: Option<[f64; 2]>,
}

/// A named group of features and groups.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Group {
    /// Short name, unique among its siblings.
    pub label: String,
    /// Free text.
    #[serde(default)]
    pub description: String,
    /// Groups and features inside.
    #[serde(default)]
    pub children: Vec<Node>,
}

/// A node of the tree.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Node {
    /// A group.
    Group(Group),
    /// A feature.
    Feature(Feature),
}

/// The feature map: the tree plus what the transfer function needs to know about the volume.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeatureMap {
    /// Always `FEATURE_MAP_VERSION`.
    pub version: u32,
    /// The feature volume's file name, relative to the map's folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub volume: Option<String>,
    /// The data range before the first migration (unmigrated data).
    pub context_range: [f64; 2],
    /// Top-level groups and features.
    #[serde(default)]
    pub nodes: Vec<Node>,
}

impl FeatureMap {
    /// An empty map over data whose range before migration is `context_range`.
    pub fn new(context_range: [f64; 2]) -> Self {
        FeatureMap {
            version: FEATURE_MAP_VERSION,
            volume: None,
            context_range,
            nodes: Vec::new(),
        }
    }

    /// Every feature with the labels of its groups, in tree order (depth first).
    pub fn features(&self) -> Vec<(Vec<&str>, &Feature)> {
        fn walk<'a>(
            nodes: &'a [Node],
            path: &mut Vec<&'a str>,
            out: &mut Vec<(Vec<&'a str>, &'a Feature)>,
        ) {
            for n in nodes {
                match n {
                    Node::Feature(f) => out.push((path.clone(), f)),
                    Node::Group(g) => {
                        path.push(&g.label);
                        walk(&g.children, path, out);
                        path.pop();
                    }
                }
            }
        }
        let mut out = Vec::new();
        walk(&self.nodes, &mut Vec::new(), &mut out);
        out
    }

    /// The feature labelled `label`, if any.
    pub fn feature(&self, label: &str) -> Option<&Feature> {
        self.features()
            .into_iter()
            .map(|(_, f)| f)
            .find(|f| f.label == label)
    }

    /// The top of the highest private interval, or `None` for a map without features.
    pub(crate) fn highest(&self) -> Option<f64> {
        self.features()
            .iter()
            .map(|(_, f)| f.interval[1])
            .reduce(f64::max)
    }

    /// The next default colour from [`PALETTE`].
    pub fn next_color(&self) -> [f32; 3] {
        PALETTE[self.features().len() % PALETTE.len()]
    }

    /// Adds `feature` under the group path `parent` ("bones" or "body/bones"; `None` for the top
    /// level), creating missing groups. The label must be new and the interval must lie above
    /// every earlier one; on any error the map is unchanged.
    pub fn append(&mut self, feature: Feature, parent: Option<&str>) -> Result<()> {
        if let Some(top) = self.highest() {
            if feature.interval[0] <= top {
                return Err(Error::Invalid(format!(
                    "feature '{}' has interval [{}, {}], which does not lie above the map's highest interval (up to {top}); expected the previous feature volume as the input",
                    feature.label, feature.interval[0], feature.interval[1]
                )));
            }
        }
        let mut next = self.clone();
        let mut nodes = &mut next.nodes;
        for label in parent.into_iter().flat_map(|p| p.split('/')).map(str::trim) {
            if label.is_empty() {
                return Err(Error::Invalid(format!(
                    "parent group '{}' has an empty part; expected labels separated by '/'",
                    parent.unwrap_or_default()
                )));
            }
            let at = nodes
                .iter()
                .position(|n| matches!(n, Node::Group(g) if g.label == label));
            let at = at.unwrap_or_else(|| {
                nodes.push(Node::Group(Group {
                    label: label.to_string(),
                    description: String::new(),
                    children: Vec::new(),
                }));
                nodes.len() - 1
            });
            nodes = match &mut nodes[at] {
                Node::Group(g) => &mut g.children,
                Node::Feature(_) => unreachable!("position() matched a group"),
            };
        }
        nodes.push(Node::Feature(feature));
        next.validate()?;
        *self = next;
        Ok(())
    }

    /// Checks the version, labels, colours and intervals (see the module doc).
    pub fn validate(&self) -> Result<()> {
        if self.version != FEATURE_MAP_VERSION {
            return Err(Error::Invalid(format!(
                "feature map version {} is not supported; expected version {FEATURE_MAP_VERSION}",
                self.version
            )));
        }
        let [c0, c1] = self.context_range;
        if !(c0.is_finite() && c1.is_finite() && c0 <= c1) {
            return Err(Error::Invalid(format!(
                "context_range [{c0}, {c1}] is invalid; expected two finite numbers, low first"
            )));
        }
        fn groups(nodes: &[Node]) -> Result<()> {
            for (i, n) in nodes.iter().enumerate() {
                if let Node::Group(g) = n {
                    if g.label.trim().is_empty() {
                        return Err(Error::Invalid(
                            "a group has an empty label; expected a name".into(),
                        ));
                    }
                    let twin = nodes[..i]
                        .iter()
                        .any(|m| matches!(m, Node::Group(h) if h.label == g.label));
                    if twin {
                        return Err(Error::Invalid(format!(
                            "group '{}' appears twice in one place; expected unique group labels among siblings",
                            g.label
                        )));
                    }
                    groups(&g.children)?;
                }
            }
            Ok(())
        }
        groups(&self.nodes)?;
        let features = self.features();
        for (i, (_, f)) in features.iter().enumerate() {
            let [lo, hi] = f.interval;
            if f.label.trim().is_empty() {
                return Err(Error::Invalid(
                    "a feature has an empty label; expected a name".into(),
                ));
            }
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return Err(Error::Invalid(format!(
                    "feature '{}' has interval [{lo}, {hi}]; expected two finite numbers, low first",
                    f.label
                )));
            }
            if !f.color.iter().all(|c| (0.0..=1.0).contains(c)) {
                return Err(Error::Invalid(format!(
                    "feature '{}' has colour {:?}; expected R, G, B in [0, 1]",
                    f.label, f.color
                )));
            }
            if lo <= c1 {
                return Err(Error::Invalid(format!(
                    "feature '{}' has interval [{lo}, {hi}], which overlaps the context range [{c0}, {c1}]; expected private intervals above the original data",
                    f.label
                )));
            }
            for (_, e) in &features[..i] {
                if e.label == f.label {
                    return Err(Error::Invalid(format!(
                        "feature label '{}' is used twice; expected unique feature labels",
                        f.label
                    )));
                }
                if lo <= e.interval[1] && e.interval[0] <= hi {
                    return Err(Error::Invalid(format!(
                        "features '{}' and '{}' have overlapping intervals; expected disjoint private intervals",
                        e.label, f.label
                    )));
                }
            }
        }
        Ok(())
    }

    /// Parses and validates the JSON form.
    pub fn from_json_str(json: &str) -> Result<Self> {
        let map: FeatureMap = serde_json::from_str(json).map_err(|e| {
            Error::Invalid(format!(
                "feature map JSON: {e}; expected {{\"version\": {FEATURE_MAP_VERSION}, \"context_range\": [lo, hi], \"nodes\": [..]}}"
            ))
        })?;
        map.validate()?;
        Ok(map)
    }

    /// The JSON form, pretty-printed.
    pub fn to_json(&self) -> String {
        // Plain structs of strings and finite floats always serialise.
        serde_json::to_string_pretty(self).expect("feature map serialises")
    }

    /// Reads and validates a map file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = crate::io::read_text(path)?;
        Self::from_json_str(&text).map_err(|e| match e {
            Error::Invalid(msg) => Error::format(path, msg),
            other => other,
        })
    }

    /// Writes the map atomically (never a partial file).
    pub fn save(&self, path: &Path) -> Result<()> {
        self.validate()?;
        let json = self.to_json();
        crate::output::write_atomic(path, |w| {
            use std::io::Write;
            w.write_all(json.as_bytes())?;
            w.write_all(b"\n")
        })
    }
}

/// The tree as text, one node a line: groups by label, features with interval and colour.
impl fmt::Display for FeatureMap {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [c0, c1] = self.context_range;
        write!(f, "feature map v{}", self.version)?;
        if let Some(v) = &self.volume {
            write!(f, " for {v}")?;
        }
        writeln!(f, ", context (unmigrated data) [{c0}, {c1}]")?;
        fn nodes(f: &mut fmt::Formatter<'_>, list: &[Node], indent: &str) -> fmt::Result {
            for (i, n) in list.iter().enumerate() {
                let last = i + 1 == list.len();
                let (branch, more) = if last {
                    ("└─ ", "   ")
                } else {
                    ("├─ ", "│  ")
                };
                let describe = |d: &str| {
                    if d.is_empty() {
                        String::new()
                    } else {
                        format!(": {d}")
                    }
                };
                match n {
                    Node::Group(g) => {
                        writeln!(
                            f,
                            "{indent}{branch}{}/{}",
                            g.label,
                            describe(&g.description)
                        )?;
                        nodes(f, &g.children, &format!("{indent}{more}"))?;
                    }
                    Node::Feature(x) => {
                        let [r, g, b] = x.color;
                        writeln!(
                            f,
                            "{indent}{branch}{}  [{}, {}]  rgb({r:.2}, {g:.2}, {b:.2}){}",
                            x.label,
                            x.interval[0],
                            x.interval[1],
                            describe(&x.description)
                        )?;
                    }
                }
            }
            Ok(())
        }
        nodes(f, &self.nodes, "")
    }
}

/// Parses a colour written as `R,G,B` with components in [0, 1].
pub fn parse_color(s: &str) -> Result<[f32; 3]> {
    let parts: Option<Vec<f32>> = s.split(',').map(|c| c.trim().parse().ok()).collect();
    parts
        .and_then(|v| <[f32; 3]>::try_from(v).ok())
        .filter(|c| c.iter().all(|x| (0.0..=1.0).contains(x)))
        .ok_or_else(|| {
            Error::Invalid(format!(
                "colour '{s}' is invalid; expected R,G,B with each component in [0, 1]"
            ))
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn feature(label: &str, interval: [f64; 2]) -> Feature {
        Feature {
            label: label.into(),
            description: format!("the {label}"),
            interval,
            color: [1.0, 0.5, 0.0],
            source_range: Some([0.0, 10.0]),
        }
    }

    #[test]
    fn append_builds_the_tree_and_round_trips() {
        let mut map = FeatureMap::new([0.0, 255.0]);
        map.volume = Some("feature.nrrd".into());
        map.append(feature("skull", [268.0, 400.0]), Some("head/bones"))
            .unwrap();
        map.append(feature("valve", [420.0, 500.0]), None).unwrap();
        map.append(feature("jaw", [520.0, 600.0]), Some("head/bones"))
            .unwrap();
        let paths: Vec<(Vec<&str>, &str)> = map
            .features()
            .iter()
            .map(|(p, f)| (p.clone(), f.label.as_str()))
            .collect();
        assert_eq!(
            paths,
            vec![
                (vec!["head", "bones"], "skull"),
                (vec!["head", "bones"], "jaw"),
                (vec![], "valve"),
            ]
        );
        assert_eq!(map.highest(), Some(600.0));
        let back = FeatureMap::from_json_str(&map.to_json()).unwrap();
        assert_eq!(back, map);
        assert!(map.to_json().contains("\"kind\": \"group\""));

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("features.json");
        map.save(&path).unwrap();
        assert_eq!(FeatureMap::load(&path).unwrap(), map);

        let text = map.to_string();
        assert!(text.contains("├─ head/"), "{text}");
        assert!(
            text.contains("skull  [268, 400]  rgb(1.00, 0.50, 0.00): the skull"),
            "{text}"
        );
        assert!(
            text.lines().last().unwrap().starts_with("└─ valve"),
            "{text}"
        );
    }

    #[test]
    fn bad_maps_say_what_was_expected() {
        let mut map = FeatureMap::new([0.0, 255.0]);
        map.append(feature("skull", [268.0, 400.0]), None).unwrap();
        for (f, parent, needle) in [
            (feature("skull", [500.0, 600.0]), None, "used twice"),
            (feature("low", [300.0, 600.0]), None, "does not lie above"),
            (feature("x", [500.0, 600.0]), Some("a//b"), "empty part"),
        ] {
            let e = map.clone().append(f, parent).unwrap_err().to_string();
            assert!(e.contains(needle), "{e}");
        }
        let mut bad = feature("red", [500.0, 600.0]);
        bad.color = [2.0, 0.0, 0.0];
        let e = map.clone().append(bad, None).unwrap_err().to_string();
        assert!(e.contains("expected R, G, B in [0, 1]"), "{e}");
        for (json, needle) in [
            (
                r#"{"version": 2, "context_range": [0, 1], "nodes": []}"#,
                "expected version 1",
            ),
            (r#"{"version": 1, "nodes": []}"#, "expected {\"version\""),
            (
                r#"{"version": 1, "context_range": [0, 1], "nodes": [{"kind": "blob"}]}"#,
                "expected {\"version\"",
            ),
            (
                r#"{"version": 1, "context_range": [0, 10], "nodes": [{"kind": "feature", "label": "a", "interval": [5, 20], "color": [1, 1, 1]}]}"#,
                "overlaps the context range",
            ),
            (
                r#"{"version": 1, "context_range": [0, 1], "nodes": [{"kind": "feature", "label": "a", "interval": [5, 20], "color": [1, 1, 1], "colour": 3}]}"#,
                "unknown field",
            ),
        ] {
            let e = FeatureMap::from_json_str(json).unwrap_err().to_string();
            assert!(e.contains(needle), "{json}: {e}");
        }
    }

    #[test]
    fn parses_colours() {
        assert_eq!(parse_color("1, 0.5,0").unwrap(), [1.0, 0.5, 0.0]);
        for bad in ["1,0", "255,0,0", "a,b,c", "1,0,0,1"] {
            let e = parse_color(bad).unwrap_err().to_string();
            assert!(e.contains("expected R,G,B"), "{bad}: {e}");
        }
        let map = FeatureMap::new([0.0, 1.0]);
        assert_eq!(map.next_color(), PALETTE[0]);
    }
}
