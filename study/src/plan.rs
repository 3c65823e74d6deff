//! The study file (TOML) and each participant's plan: which condition in which position,
//! recomputable from the participant number alone (a balanced Latin square).
//!
//! Every key is documented in `examples/study/study1.toml`. A file is checked completely
//! when it is read ([`Study::load`]): unknown keys, a model file that is missing or does not
//! load, a start pose the robot does not have, duplicate labels, a scale without items. The
//! error names the file and the key.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::StudyError;

/// The NASA-TLX subscales, in the order they are asked (raw TLX, 0 to 100 in steps of 5).
pub const TLX_SUBSCALES: [&str; 6] = [
    "mental demand",
    "physical demand",
    "temporal demand",
    "performance",
    "effort",
    "frustration",
];

/// A study as written in its file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StudyFile {
    /// The study's name (shown to the experimenter, written to the data).
    pub name: String,
    /// How many participants the plan has: `P01` to `P<n>`.
    pub participants: u32,
    /// The tasks, in the order every participant does them.
    pub tasks: Vec<Task>,
    /// The conditions (maps); each participant meets them in their Latin-square order.
    pub conditions: Vec<Condition>,
    /// The questionnaire after each condition of each task.
    #[serde(default)]
    pub questionnaire: Questionnaire,
    /// The simulated participants' operator (`scl study simulate`); defaults where absent.
    #[serde(default)]
    pub simulation: crate::simulate::SimParams,
}

/// One task.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Task {
    /// Its name (file names, the report).
    pub name: String,
    /// The start pose: a named pose of the robot (`home`) or a joint vector (rad).
    pub start: StartPose,
    /// The fastest joint's speed on the way to the start pose (rad/s).
    #[serde(default = "default_approach_speed")]
    pub approach_speed_rad_s: f64,
    /// An attempt ends as a timeout after this long (s).
    pub time_limit_s: f64,
    /// Practice with each condition before its attempts (s); 0 for none.
    #[serde(default)]
    pub practice_s: f64,
    /// Attempts per condition.
    pub attempts: u32,
    /// Simulated participants: which task's goals this is (`table-cleaning`,
    /// `pick-and-place`, `pouring`); default: the task's name.
    #[serde(default)]
    pub goals: Option<String>,
    /// Simulated participants: position tolerance of the goals (m); default 0.03.
    #[serde(default)]
    pub tolerance_m: Option<f64>,
    /// Simulated pouring: the tilt that pours (degrees); default 90.
    #[serde(default)]
    pub pour_angle_deg: Option<f64>,
    /// Simulated pouring: how long the pour is held (s); default 1.
    #[serde(default)]
    pub hold_s: Option<f64>,
    /// Simulated pouring: the tilt that counts as upright again (degrees); default 20.
    #[serde(default)]
    pub upright_deg: Option<f64>,
}

fn default_approach_speed() -> f64 {
    mapper::goto::DEFAULT_SPEED_RAD_S
}

/// A task's start pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum StartPose {
    /// A named pose of the robot profile.
    Named(String),
    /// Joint positions (rad).
    Joints(Vec<f64>),
}

/// One condition: a map behind a blind label.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Condition {
    /// What the participant and the experimenter see (`A`, `B`, `C`).
    pub label: String,
    /// What the data and the report call it (`SCL`); never shown during the study.
    pub name: String,
    /// The model: a file (relative to the study file), `bundled`, or `modeswitch[:...]`;
    /// or a table with one per task (`model = { pouring = "scl-pouring.safetensors" }`, as
    /// the paper trained one model per task).
    pub model: ModelRef,
}

/// A condition's model: one for every task, or one per task.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ModelRef {
    /// The same model for every task.
    One(String),
    /// A model per task name.
    PerTask(std::collections::BTreeMap<String, String>),
}

/// The questionnaire after each condition.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Questionnaire {
    /// The Likert scale's top answer (1 to `scale`).
    #[serde(default = "default_scale")]
    pub scale: u32,
    /// The Likert items (statements rated 1 = strongly disagree to `scale` = strongly agree).
    #[serde(default)]
    pub likert: Vec<String>,
    /// Ask NASA-TLX's six subscales (0 to 100 in steps of 5).
    #[serde(default)]
    pub nasa_tlx: bool,
}

fn default_scale() -> u32 {
    7
}

impl Default for Questionnaire {
    fn default() -> Self {
        Self {
            scale: default_scale(),
            likert: Vec::new(),
            nasa_tlx: false,
        }
    }
}

/// One question of the questionnaire and its answer's range.
#[derive(Debug, Clone, PartialEq)]
pub struct Question {
    /// `likert` or `tlx`.
    pub kind: &'static str,
    /// The item's text (Likert) or the subscale's name (TLX).
    pub item: String,
    /// Smallest answer.
    pub min: u32,
    /// Largest answer.
    pub max: u32,
    /// Answers must be multiples of this.
    pub step: u32,
}

impl Question {
    /// Checks an answer.
    pub fn check(&self, v: u32) -> Result<(), String> {
        if v < self.min || v > self.max || !v.is_multiple_of(self.step) {
            return Err(format!(
                "`{}`: {v} is not an answer; it takes {}..={}{}",
                self.item,
                self.min,
                self.max,
                if self.step > 1 {
                    format!(" in steps of {}", self.step)
                } else {
                    String::new()
                }
            ));
        }
        Ok(())
    }
}

impl Questionnaire {
    /// The questions in the order they are asked.
    pub fn questions(&self) -> Vec<Question> {
        let mut q: Vec<Question> = self
            .likert
            .iter()
            .map(|item| Question {
                kind: "likert",
                item: item.clone(),
                min: 1,
                max: self.scale,
                step: 1,
            })
            .collect();
        if self.nasa_tlx {
            q.extend(TLX_SUBSCALES.iter().map(|s| Question {
                kind: "tlx",
                item: (*s).to_owned(),
                min: 0,
                max: 100,
                step: 5,
            }));
        }
        q
    }
}

/// A checked study: its file, where it lives (model paths are relative to it), and the models
/// resolved.
#[derive(Debug, Clone)]
pub struct Study {
    /// The file as written.
    pub file: StudyFile,
    /// Where it was read from.
    pub path: PathBuf,
    /// Each condition's model per task (indexed like `file.tasks`) as the graph takes it (an
    /// absolute path or a built-in spec).
    pub models: Vec<Vec<String>>,
    /// The file's text (copied next to each participant's data).
    pub text: String,
}

impl Study {
    /// Reads and checks the study file at `path` for the robot `robot`.
    pub fn load(path: &Path, robot: &'static kinematics::RobotProfile) -> Result<Self, StudyError> {
        let text = std::fs::read_to_string(path).map_err(|source| StudyError::Read {
            path: path.to_owned(),
            source,
        })?;
        Self::parse(&text, path, robot)
    }

    /// Parses and checks a study file's `text`; `path` names it and anchors model paths.
    pub fn parse(
        text: &str,
        path: &Path,
        robot: &'static kinematics::RobotProfile,
    ) -> Result<Self, StudyError> {
        let file: StudyFile = toml::from_str(text).map_err(|e| StudyError::Parse {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        let bad = |key: String, reason: String| StudyError::Invalid {
            path: path.to_owned(),
            key,
            reason,
        };
        if file.participants == 0 {
            return Err(bad("participants".into(), "must be at least 1".into()));
        }
        if file.tasks.is_empty() {
            return Err(bad("tasks".into(), "the study has no task".into()));
        }
        if file.conditions.len() < 2 {
            return Err(bad(
                "conditions".into(),
                "a study compares at least two conditions".into(),
            ));
        }
        let mut names = BTreeSet::new();
        for (i, t) in file.tasks.iter().enumerate() {
            check_task(path, robot, i, t, &mut names)?;
        }
        let mut labels = BTreeSet::new();
        let mut models = Vec::new();
        let base = path.parent().unwrap_or(Path::new("."));
        for (i, c) in file.conditions.iter().enumerate() {
            let ctx = ConditionCheck {
                path,
                robot,
                base,
                tasks: &file.tasks,
                names: &names,
            };
            models.push(ctx.models(i, c, &mut labels)?);
        }
        file.simulation
            .check()
            .map_err(|(key, reason)| bad(key, reason))?;
        let q = &file.questionnaire;
        if !q.likert.is_empty() && q.scale < 2 {
            return Err(bad(
                "questionnaire.scale".into(),
                format!("{} leaves nothing to choose; use 5 or 7", q.scale),
            ));
        }
        Ok(Self {
            file,
            path: path.to_owned(),
            models,
            text: text.to_owned(),
        })
    }

    /// Participant `id` (`P03`, `p3` or `3`) as a number of the plan, or an error saying
    /// which numbers the plan has.
    pub fn participant(&self, id: &str) -> Result<Participant, StudyError> {
        let digits = id.trim().trim_start_matches(['P', 'p']);
        let n: u32 = digits.parse().map_err(|_| StudyError::Participant {
            id: id.to_owned(),
            reason: "write it as P<number>, e.g. P03".into(),
        })?;
        if n == 0 || n > self.file.participants {
            return Err(StudyError::Participant {
                id: id.to_owned(),
                reason: format!(
                    "the plan of {} has P01 to {}",
                    self.path.display(),
                    Participant(self.file.participants)
                ),
            });
        }
        Ok(Participant(n))
    }

    /// The order in which `p` meets the conditions (indices into `file.conditions`).
    pub fn order(&self, p: Participant) -> Vec<usize> {
        latin_row(self.file.conditions.len(), p.0)
    }
}

/// Checks task `i` of a study file (`path`): a unique file-safe name, a positive time
/// limit and attempts, plausible tolerances, a start pose `robot` can go to.
fn check_task(
    path: &Path,
    robot: &'static kinematics::RobotProfile,
    i: usize,
    t: &Task,
    names: &mut BTreeSet<String>,
) -> Result<(), StudyError> {
    let bad = |key: String, reason: String| StudyError::Invalid {
        path: path.to_owned(),
        key,
        reason,
    };
    let key = |k: &str| format!("tasks[{i}].{k}");
    unique_file_name(&t.name, names).map_err(|r| bad(key("name"), r))?;
    if !(t.time_limit_s.is_finite() && t.time_limit_s > 0.0) {
        return Err(bad(key("time_limit_s"), "must be positive".into()));
    }
    if !(t.practice_s.is_finite() && t.practice_s >= 0.0) {
        return Err(bad(key("practice_s"), "must be 0 or more".into()));
    }
    if t.attempts == 0 {
        return Err(bad(key("attempts"), "must be at least 1".into()));
    }
    for (k, v, hi) in [
        ("tolerance_m", t.tolerance_m, 1.0),
        ("pour_angle_deg", t.pour_angle_deg, 180.0),
        ("hold_s", t.hold_s, 3600.0),
        ("upright_deg", t.upright_deg, 180.0),
    ] {
        if let Some(v) = v
            && !(v.is_finite() && v > 0.0 && v <= hi)
        {
            return Err(bad(key(k), format!("{v} is not in (0, {hi}]")));
        }
    }
    mapper::goto::GotoMap::from_spec_for(robot, &t.goto_spec())
        .map_err(|e| bad(key("start"), e.to_string()))?;
    Ok(())
}

/// What a condition of a study file is checked against: the file, the arm, the directory
/// its model paths are relative to, and the tasks (with their names).
struct ConditionCheck<'a> {
    path: &'a Path,
    robot: &'static kinematics::RobotProfile,
    base: &'a Path,
    tasks: &'a [Task],
    names: &'a BTreeSet<String>,
}

impl ConditionCheck<'_> {
    /// Checks condition `i` (a unique file-safe label; models naming only the study's
    /// tasks, one for each, each loading for the arm); its model spec per task.
    fn models(
        &self,
        i: usize,
        c: &Condition,
        labels: &mut BTreeSet<String>,
    ) -> Result<Vec<String>, StudyError> {
        let (path, robot, base, tasks, names) =
            (self.path, self.robot, self.base, self.tasks, self.names);
        let bad = |key: String, reason: String| StudyError::Invalid {
            path: path.to_owned(),
            key,
            reason,
        };
        let key = |k: &str| format!("conditions[{i}].{k}");
        unique_file_name(&c.label, labels).map_err(|r| bad(key("label"), r))?;
        if let ModelRef::PerTask(m) = &c.model
            && let Some(t) = m.keys().find(|t| !names.contains(*t))
        {
            return Err(bad(
                format!("{}.{t}", key("model")),
                "names no task of the study".into(),
            ));
        }
        let mut per_task = Vec::new();
        for t in tasks {
            let (model, k) = match &c.model {
                ModelRef::One(m) => (m, key("model")),
                ModelRef::PerTask(m) => {
                    let k = format!("{}.{}", key("model"), t.name);
                    (
                        m.get(&t.name).ok_or_else(|| {
                            bad(k.clone(), "missing: every task needs a model".into())
                        })?,
                        k,
                    )
                }
            };
            let spec = if mapper::model::is_builtin(model) {
                model.clone()
            } else {
                let p = base.join(model);
                let abs = std::fs::canonicalize(&p)
                    .map_err(|e| bad(k.clone(), format!("`{}`: {e}", p.display())))?;
                abs.display().to_string()
            };
            mapper::LoadedModel::load_for(&spec, robot).map_err(|e| bad(k, e.to_string()))?;
            per_task.push(spec);
        }
        Ok(per_task)
    }
}

impl Task {
    /// The goals' tolerances: the keys given, the defaults of
    /// [`learning::goals::Tolerances`] for the rest.
    pub fn tolerances(&self) -> learning::goals::Tolerances {
        let d = learning::goals::Tolerances::default();
        learning::goals::Tolerances {
            position_m: self.tolerance_m.unwrap_or(d.position_m),
            pour_angle_rad: self
                .pour_angle_deg
                .map_or(d.pour_angle_rad, f64::to_radians),
            hold_s: self.hold_s.unwrap_or(d.hold_s),
            upright_rad: self.upright_deg.map_or(d.upright_rad, f64::to_radians),
        }
    }

    /// The go-to map's spec for the start pose.
    pub fn goto_spec(&self) -> String {
        let pose = match &self.start {
            StartPose::Named(n) => format!("pose={n}"),
            StartPose::Joints(q) => format!(
                "q={}",
                q.iter().map(f64::to_string).collect::<Vec<_>>().join(",")
            ),
        };
        format!("goto:{pose};speed={}", self.approach_speed_rad_s)
    }
}

/// A participant of the plan, numbered from 1; shown as `P03`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Participant(pub u32);

impl std::fmt::Display for Participant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "P{:02}", self.0)
    }
}

fn is_file_name(s: &str) -> bool {
    !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

/// Takes `name` into `seen` if it is a file-safe name not taken yet; else why not.
fn unique_file_name(name: &str, seen: &mut BTreeSet<String>) -> Result<(), String> {
    if is_file_name(name) && seen.insert(name.to_owned()) {
        Ok(())
    } else {
        Err(format!(
            "`{name}` must be unique and use only letters, digits, '-' and '_'"
        ))
    }
}

/// The rows of the balanced Latin square (Williams design) over `k` conditions: `k` rows for
/// an even `k`, `2k` (each row and its mirror) for an odd one. Over all rows every condition
/// takes every position equally often and every ordered pair of conditions follows
/// immediately equally often.
pub fn latin_square(k: usize) -> Vec<Vec<usize>> {
    if k == 0 {
        return Vec::new();
    }
    // First row 0, 1, k-1, 2, k-2, ... (Williams); row r adds r to each entry.
    let mut first = Vec::with_capacity(k);
    let (mut lo, mut hi) = (0usize, k);
    for i in 0..k {
        if i == 0 || i % 2 == 1 {
            first.push(lo);
            lo += 1;
        } else {
            hi -= 1;
            first.push(hi);
        }
    }
    let mut rows: Vec<Vec<usize>> = (0..k)
        .map(|r| first.iter().map(|c| (c + r) % k).collect())
        .collect();
    if k % 2 == 1 {
        let mirrored: Vec<Vec<usize>> = rows
            .iter()
            .map(|r| r.iter().rev().copied().collect())
            .collect();
        rows.extend(mirrored);
    }
    rows
}

/// Participant `n`'s row (from 1): row `(n - 1) mod rows` of [`latin_square`].
pub fn latin_row(k: usize, n: u32) -> Vec<usize> {
    let mut rows = latin_square(k);
    if rows.is_empty() {
        return Vec::new();
    }
    let i = (n.max(1) as usize - 1) % rows.len();
    rows.swap_remove(i)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Over a full block: each condition in each position equally often; for an even count
    /// (or the doubled square of an odd one) each ordered pair adjacent equally often.
    fn check_balanced(k: usize) {
        let rows = latin_square(k);
        assert_eq!(rows.len(), if k.is_multiple_of(2) { k } else { 2 * k });
        let per_cell = rows.len() / k;
        for pos in 0..k {
            for c in 0..k {
                let n = rows.iter().filter(|r| r[pos] == c).count();
                assert_eq!(n, per_cell, "k={k}: condition {c} at position {pos}");
            }
        }
        for r in &rows {
            let mut seen = r.clone();
            seen.sort_unstable();
            assert_eq!(seen, (0..k).collect::<Vec<_>>(), "k={k}: {r:?} is no order");
        }
        let per_pair = rows.len() / k;
        for a in 0..k {
            for b in 0..k {
                if a == b {
                    continue;
                }
                let n = rows
                    .iter()
                    .flat_map(|r| r.windows(2))
                    .filter(|w| w[0] == a && w[1] == b)
                    .count();
                assert_eq!(n, per_pair, "k={k}: {a} then {b}");
            }
        }
    }

    #[test]
    fn the_latin_square_is_balanced() {
        for k in 2..=8 {
            check_balanced(k);
        }
        // The paper's three conditions: six orders, each once.
        let rows = latin_square(3);
        let mut sorted = rows.clone();
        sorted.sort();
        sorted.dedup();
        assert_eq!(sorted.len(), 6);
    }

    proptest! {
        #[test]
        fn a_participants_order_is_recomputable_and_cycles_with_the_square(
            k in 2usize..9, n in 1u32..500,
        ) {
            let rows = latin_square(k);
            let r = latin_row(k, n);
            prop_assert_eq!(&r, &latin_row(k, n));
            prop_assert_eq!(&r, &latin_row(k, n + rows.len() as u32));
            prop_assert_eq!(&r, &rows[(n as usize - 1) % rows.len()]);
        }
    }

    fn robot() -> &'static kinematics::RobotProfile {
        kinematics::RobotProfile::default_robot()
    }

    const GOOD: &str = r#"
name = "t"
participants = 4
[[tasks]]
name = "reach"
start = "home"
time_limit_s = 10
attempts = 2
[[conditions]]
label = "A"
name = "SCL"
model = "bundled"
[[conditions]]
label = "B"
name = "modes"
model = "modeswitch"
[questionnaire]
likert = ["I felt in control"]
nasa_tlx = true
"#;

    #[test]
    fn a_good_file_loads_and_participants_outside_the_plan_are_refused() {
        let s = Study::parse(GOOD, Path::new("s.toml"), robot()).unwrap();
        assert_eq!(s.models, [["bundled"], ["modeswitch"]]);
        assert_eq!(s.participant("P03").unwrap(), Participant(3));
        assert_eq!(s.participant("4").unwrap().to_string(), "P04");
        for id in ["P00", "P05", "x"] {
            let e = s.participant(id).unwrap_err().to_string();
            assert!(e.contains(id), "{e}");
        }
        assert_eq!(s.order(Participant(1)), [0, 1]);
        assert_eq!(s.order(Participant(2)), [1, 0]);
        let q = s.file.questionnaire.questions();
        assert_eq!(q.len(), 7);
        assert!(q[0].check(7).is_ok() && q[0].check(8).is_err() && q[0].check(0).is_err());
        assert!(q[1].check(55).is_ok() && q[1].check(52).is_err() && q[1].check(105).is_err());
        assert_eq!(
            s.file.tasks[0].goto_spec(),
            format!("goto:pose=home;speed={}", mapper::goto::DEFAULT_SPEED_RAD_S)
        );
    }

    #[test]
    fn the_example_studies_use_only_known_keys_and_a_square_per_participant() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/study");
        for name in ["study1.toml", "study2.toml"] {
            let text = std::fs::read_to_string(dir.join(name)).unwrap();
            let f: StudyFile = toml::from_str(&text).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(f.conditions.len(), 3, "{name}");
            assert_eq!(
                f.simulation,
                crate::simulate::SimParams::default(),
                "{name}: the documented defaults"
            );
            for t in &f.tasks {
                assert_eq!(
                    t.tolerances(),
                    learning::goals::Tolerances::default(),
                    "{name}"
                );
            }
            assert!(
                f.questionnaire.nasa_tlx && f.questionnaire.likert.len() == 5,
                "{name}"
            );
        }
    }

    /// The study files write table cleaning's start as joint angles (a study file names a pose
    /// or angles); they are the task's own start (`learning::tasks::start_pose`, which `scl
    /// eval capability` uses) to the written three decimals, so the two cannot drift apart.
    #[test]
    fn the_example_studies_start_table_cleaning_at_the_tasks_start() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/study");
        for (name, robot) in [
            ("study1.toml", kinematics::RobotProfile::default_name()),
            ("calibration.toml", kinematics::RobotProfile::default_name()),
            ("feasibility.toml", kinematics::RobotProfile::default_name()),
            ("gen3.toml", "gen3"),
        ] {
            let robot = kinematics::RobotProfile::by_name(robot).unwrap();
            let want =
                learning::tasks::start_pose(robot, learning::tasks::Task::TableCleaning).unwrap();
            let want: Vec<f64> = want.iter().map(|a| (a * 1e3).round() / 1e3).collect();
            let text = std::fs::read_to_string(dir.join(name)).unwrap();
            let f: StudyFile = toml::from_str(&text).unwrap_or_else(|e| panic!("{name}: {e}"));
            let t = f.tasks.iter().find(|t| t.name == "table-cleaning");
            let t = t.unwrap_or_else(|| panic!("{name}: no table-cleaning task"));
            match &t.start {
                StartPose::Joints(q) => {
                    let off = q.iter().zip(&want).map(|(a, b)| (a - b).abs());
                    assert!(
                        q.len() == want.len() && off.fold(0.0, f64::max) < 6e-4,
                        "{name}: start = {q:?}, the task's start is {want:?}"
                    );
                }
                StartPose::Named(n) => panic!("{name}: start = {n:?}, not the task's start"),
            }
        }
    }

    #[test]
    fn bad_files_name_the_file_and_the_key() {
        for (edit, key, says) in [
            (
                ("attempts = 2", "attempts = 2\ncolour = 1"),
                "",
                "unknown field `colour`",
            ),
            (
                ("model = \"bundled\"", "model = \"missing.safetensors\""),
                "conditions[0].model",
                "missing.safetensors",
            ),
            (
                ("start = \"home\"", "start = \"moon\""),
                "tasks[0].start",
                "no pose `moon`",
            ),
            (
                ("label = \"B\"", "label = \"A\""),
                "conditions[1].label",
                "unique",
            ),
            (
                ("attempts = 2", "attempts = 0"),
                "tasks[0].attempts",
                "at least 1",
            ),
            (
                ("model = \"bundled\"", "model = { other = \"bundled\" }"),
                "conditions[0].model.other",
                "names no task",
            ),
            (
                (
                    "model = \"bundled\"",
                    "model = { reach = \"nope.safetensors\" }",
                ),
                "conditions[0].model.reach",
                "nope.safetensors",
            ),
            (
                ("participants = 4", "participants = 0"),
                "participants",
                "at least 1",
            ),
        ] {
            let text = GOOD.replacen(edit.0, edit.1, 1);
            let e = Study::parse(&text, Path::new("dir/s.toml"), robot())
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("dir/s.toml") && e.contains(key) && e.contains(says),
                "{e}"
            );
        }
    }
}
