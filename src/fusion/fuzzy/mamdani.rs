//! A small, general Mamdani fuzzy inference system: linguistic variables
//! with triangular, trapezoidal and Gaussian memberships, rules whose
//! antecedents combine terms with AND (min), OR (max) and NOT (1 − μ),
//! implication by min, aggregation by max, and centroid defuzzification.
//!
//! Discretisation: the output variable's range is sampled at
//! `resolution` evenly spaced points, ends included (default 201), and the
//! centroid is Σ yᵢ·μ(yᵢ) / Σ μ(yᵢ) over them. Each output term's
//! membership at those points is tabulated once; rules with the same
//! output term are combined first (max of the firings), since
//! max(min(w₁, μ), min(w₂, μ)) = min(max(w₁, w₂), μ). So an inference costs
//! one pass over the points per output term, whatever the number of rules.
//!
//! Written here rather than taken from a crate: the few fuzzy crates seen
//! either lack Mamdani centroid defuzzification with a stated
//! discretisation or allocate per inference, and the whole is ~300 lines.

use serde::{Deserialize, Serialize};

/// A membership function μ(x) ∈ [0, 1].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Membership {
    /// 0 at `a`, 1 at `b`, 0 at `c` (a ≤ b ≤ c; a = b or b = c make a
    /// vertical edge).
    Triangular { a: f64, b: f64, c: f64 },
    /// 0 at `a`, 1 from `b` to `c`, 0 at `d`. `a = b = −∞` or
    /// `c = d = +∞` make an open shoulder (1 out to that side).
    Trapezoidal { a: f64, b: f64, c: f64, d: f64 },
    /// exp(−(x − centre)² / (2σ²)).
    Gaussian { centre: f64, sigma: f64 },
}

impl Membership {
    /// The degree of membership of `x`.
    pub fn degree(&self, x: f64) -> f64 {
        match *self {
            Membership::Triangular { a, b, c } => trapezoid(x, a, b, b, c),
            Membership::Trapezoidal { a, b, c, d } => trapezoid(x, a, b, c, d),
            Membership::Gaussian { centre, sigma } => {
                let z = (x - centre) / sigma;
                (-0.5 * z * z).exp()
            }
        }
    }

    /// Checks the shape's parameters.
    fn validate(&self) -> Result<(), FuzzyError> {
        let ok = match *self {
            Membership::Triangular { a, b, c } => {
                a.is_finite() && b.is_finite() && c.is_finite() && a <= b && b <= c && a < c
            }
            Membership::Trapezoidal { a, b, c, d } => {
                !a.is_nan()
                    && !b.is_nan()
                    && !c.is_nan()
                    && !d.is_nan()
                    && a <= b
                    && b <= c
                    && c <= d
                    && a < d
                    && (a.is_finite() || a == b)
                    && (d.is_finite() || c == d)
            }
            Membership::Gaussian { centre, sigma } => {
                centre.is_finite() && sigma > 0.0 && sigma.is_finite()
            }
        };
        if ok {
            Ok(())
        } else {
            Err(FuzzyError::Shape(format!("{self:?}")))
        }
    }
}

fn trapezoid(x: f64, a: f64, b: f64, c: f64, d: f64) -> f64 {
    if x < a {
        0.0
    } else if x < b {
        (x - a) / (b - a)
    } else if x <= c {
        1.0
    } else if x < d {
        (d - x) / (d - c)
    } else {
        0.0
    }
}

/// A linguistic variable: a name, the range it is defuzzified over (for an
/// output) and its named terms.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Variable {
    pub name: String,
    pub min: f64,
    pub max: f64,
    pub terms: Vec<(String, Membership)>,
}

impl Variable {
    /// A variable over `[min, max]` with the given terms.
    pub fn new(name: &str, min: f64, max: f64, terms: &[(&str, Membership)]) -> Variable {
        Variable {
            name: name.to_string(),
            min,
            max,
            terms: terms.iter().map(|(n, m)| (n.to_string(), *m)).collect(),
        }
    }

    /// The index of a term by name.
    pub fn term(&self, name: &str) -> Result<usize, FuzzyError> {
        self.terms
            .iter()
            .position(|(n, _)| n == name)
            .ok_or_else(|| FuzzyError::UnknownTerm {
                variable: self.name.clone(),
                term: name.to_string(),
            })
    }
}

/// A rule's antecedent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Antecedent {
    /// Input `input` is its term `term` (indices).
    Is { input: usize, term: usize },
    /// All of them (min).
    And(Vec<Antecedent>),
    /// Any of them (max).
    Or(Vec<Antecedent>),
    /// 1 − μ.
    Not(Box<Antecedent>),
}

impl Antecedent {
    /// The firing strength given every input term's degree, flattened
    /// (`offsets[input] + term`).
    fn firing(&self, degrees: &[f64], offsets: &[usize]) -> f64 {
        match self {
            Antecedent::Is { input, term } => degrees[offsets[*input] + *term],
            Antecedent::And(parts) => parts
                .iter()
                .map(|p| p.firing(degrees, offsets))
                .fold(1.0, f64::min),
            Antecedent::Or(parts) => parts
                .iter()
                .map(|p| p.firing(degrees, offsets))
                .fold(0.0, f64::max),
            Antecedent::Not(part) => 1.0 - part.firing(degrees, offsets),
        }
    }

    fn check(&self, inputs: &[Variable]) -> Result<(), FuzzyError> {
        match self {
            Antecedent::Is { input, term } => {
                let variable = inputs.get(*input).ok_or(FuzzyError::Index)?;
                variable.terms.get(*term).ok_or(FuzzyError::Index)?;
                Ok(())
            }
            Antecedent::And(parts) | Antecedent::Or(parts) => {
                if parts.is_empty() {
                    return Err(FuzzyError::EmptyRule);
                }
                parts.iter().try_for_each(|p| p.check(inputs))
            }
            Antecedent::Not(part) => part.check(inputs),
        }
    }
}

/// IF antecedent THEN output is `term`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Rule {
    pub antecedent: Antecedent,
    pub term: usize,
}

/// Why a system could not be built or could not infer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FuzzyError {
    #[error("membership function {0} has invalid parameters")]
    Shape(String),
    #[error("variable `{variable}` has no term `{term}`")]
    UnknownTerm { variable: String, term: String },
    #[error("a rule refers to a variable or term that does not exist")]
    Index,
    #[error("a rule has an empty AND/OR")]
    EmptyRule,
    #[error("the output range must be finite with min < max, and the resolution at least 2")]
    OutputRange,
    #[error("expected {expected} inputs, got {got}")]
    Inputs { expected: usize, got: usize },
}

/// A Mamdani system with one output.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Mamdani {
    inputs: Vec<Variable>,
    output: Variable,
    rules: Vec<Rule>,
    /// Output sample points and each output term's membership at them.
    points: Vec<f64>,
    tables: Vec<Vec<f64>>,
    /// Where each input's term degrees start in the flattened degrees.
    offsets: Vec<usize>,
}

/// Reusable buffers for [`Mamdani::infer_with`], so a caller inferring at
/// every sample allocates nothing. It also remembers the last aggregate:
/// when the output terms' strengths repeat (a machine that stays fully
/// static or fully moving), the centroid is not summed again.
#[derive(Debug, Clone, Default)]
pub struct Scratch {
    degrees: Vec<f64>,
    strength: Vec<f64>,
    aggregate: Vec<f64>,
    last: Option<(Vec<f64>, Option<f64>)>,
}

impl Mamdani {
    /// Builds and checks a system; the output is discretised at
    /// `resolution` points over its range.
    pub fn new(
        inputs: Vec<Variable>,
        output: Variable,
        rules: Vec<Rule>,
        resolution: usize,
    ) -> Result<Mamdani, FuzzyError> {
        if !(output.min.is_finite() && output.max.is_finite() && output.min < output.max)
            || resolution < 2
        {
            return Err(FuzzyError::OutputRange);
        }
        for variable in inputs.iter().chain(std::iter::once(&output)) {
            variable.terms.iter().try_for_each(|(_, m)| m.validate())?;
        }
        for rule in &rules {
            rule.antecedent.check(&inputs)?;
            output.terms.get(rule.term).ok_or(FuzzyError::Index)?;
        }
        let step = (output.max - output.min) / (resolution - 1) as f64;
        let points: Vec<f64> = (0..resolution)
            .map(|i| output.min + step * i as f64)
            .collect();
        let tables = output
            .terms
            .iter()
            .map(|(_, m)| points.iter().map(|&y| m.degree(y)).collect())
            .collect();
        let offsets = inputs
            .iter()
            .scan(0, |start, v| {
                let offset = *start;
                *start += v.terms.len();
                Some(offset)
            })
            .collect();
        Ok(Mamdani {
            inputs,
            output,
            rules,
            points,
            tables,
            offsets,
        })
    }

    /// The input variables.
    pub fn inputs(&self) -> &[Variable] {
        &self.inputs
    }

    /// The output variable.
    pub fn output(&self) -> &Variable {
        &self.output
    }

    /// Each rule's firing strength for these input values.
    pub fn firings(&self, values: &[f64]) -> Result<Vec<f64>, FuzzyError> {
        let mut degrees = Vec::new();
        self.fuzzify(values, &mut degrees)?;
        Ok(self
            .rules
            .iter()
            .map(|r| r.antecedent.firing(&degrees, &self.offsets))
            .collect())
    }

    /// Every input term's degree, flattened into `degrees`.
    fn fuzzify(&self, values: &[f64], degrees: &mut Vec<f64>) -> Result<(), FuzzyError> {
        if values.len() != self.inputs.len() {
            return Err(FuzzyError::Inputs {
                expected: self.inputs.len(),
                got: values.len(),
            });
        }
        degrees.clear();
        for (variable, &x) in self.inputs.iter().zip(values) {
            degrees.extend(variable.terms.iter().map(|(_, m)| m.degree(x)));
        }
        Ok(())
    }

    /// The crisp output: centroid of the aggregated output set, or `None`
    /// when no rule fires at all.
    pub fn infer(&self, values: &[f64]) -> Result<Option<f64>, FuzzyError> {
        self.infer_with(values, &mut Scratch::default())
    }

    /// [`Mamdani::infer`] with caller-owned buffers.
    pub fn infer_with(
        &self,
        values: &[f64],
        scratch: &mut Scratch,
    ) -> Result<Option<f64>, FuzzyError> {
        self.fuzzify(values, &mut scratch.degrees)?;
        // Rules with the same output term combine by max first.
        let strength = &mut scratch.strength;
        strength.clear();
        strength.resize(self.output.terms.len(), 0.0);
        for rule in &self.rules {
            let w = rule.antecedent.firing(&scratch.degrees, &self.offsets);
            strength[rule.term] = strength[rule.term].max(w);
        }
        if let Some((last_strength, last_output)) = &scratch.last
            && last_strength == strength
        {
            return Ok(*last_output);
        }
        let output = self.centroid(strength, &mut scratch.aggregate);
        match &mut scratch.last {
            Some((last_strength, last_output)) => {
                last_strength.clone_from(strength);
                *last_output = output;
            }
            None => scratch.last = Some((strength.clone(), output)),
        }
        Ok(output)
    }

    /// Centroid of the aggregate max_k min(w_k, μ_k(y)) over the points;
    /// terms that do not fire add nothing and are skipped.
    fn centroid(&self, strength: &[f64], aggregate: &mut Vec<f64>) -> Option<f64> {
        // Plain comparisons rather than f64::min/max: no NaN can occur
        // here (strengths and tables are in [0, 1]), and they vectorise.
        aggregate.clear();
        aggregate.resize(self.points.len(), 0.0);
        for (&w, table) in strength.iter().zip(&self.tables) {
            if w > 0.0 {
                for (mu, &m) in aggregate.iter_mut().zip(table) {
                    let clipped = if m < w { m } else { w };
                    if clipped > *mu {
                        *mu = clipped;
                    }
                }
            }
        }
        let (mut moment, mut area) = (0.0, 0.0);
        for (&y, &mu) in self.points.iter().zip(aggregate.iter()) {
            moment += y * mu;
            area += mu;
        }
        (area > 0.0).then(|| moment / area)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EPS: f64 = 1e-12;

    #[test]
    fn memberships_by_hand() {
        let tri = Membership::Triangular {
            a: 0.0,
            b: 2.0,
            c: 6.0,
        };
        assert_eq!(tri.degree(-1.0), 0.0);
        assert!((tri.degree(1.0) - 0.5).abs() < EPS);
        assert_eq!(tri.degree(2.0), 1.0);
        assert!((tri.degree(5.0) - 0.25).abs() < EPS);
        assert_eq!(tri.degree(6.0), 0.0);
        let trap = Membership::Trapezoidal {
            a: 1.0,
            b: 2.0,
            c: 3.0,
            d: 5.0,
        };
        assert!((trap.degree(1.5) - 0.5).abs() < EPS);
        assert_eq!(trap.degree(2.5), 1.0);
        assert!((trap.degree(4.5) - 0.25).abs() < EPS);
        let shoulder = Membership::Trapezoidal {
            a: f64::NEG_INFINITY,
            b: f64::NEG_INFINITY,
            c: 1.0,
            d: 2.0,
        };
        assert_eq!(shoulder.degree(-1e9), 1.0);
        assert!((shoulder.degree(1.5) - 0.5).abs() < EPS);
        let gauss = Membership::Gaussian {
            centre: 1.0,
            sigma: 2.0,
        };
        assert_eq!(gauss.degree(1.0), 1.0);
        assert!((gauss.degree(3.0) - (-0.5_f64).exp()).abs() < EPS);
    }

    /// Two rectangles: "low" = 1 on [0, 4] fired at 1, "high" = 1 on
    /// [6, 10] fired at 0.5. Continuous centroid (8 + 0.5·32)/(4 + 0.5·4)
    /// = 4; with 201 points (step 0.05) the sums are 486 / 121.5 = 4 too.
    #[test]
    fn centroid_of_two_clipped_rectangles() {
        let input = Variable::new(
            "x",
            0.0,
            1.0,
            &[
                (
                    "a",
                    Membership::Triangular {
                        a: 0.0,
                        b: 0.0,
                        c: 1.0,
                    },
                ),
                (
                    "b",
                    Membership::Triangular {
                        a: 0.0,
                        b: 1.0,
                        c: 1.0,
                    },
                ),
            ],
        );
        let output = Variable::new(
            "y",
            0.0,
            10.0,
            &[
                (
                    "low",
                    Membership::Trapezoidal {
                        a: 0.0,
                        b: 0.0,
                        c: 4.0,
                        d: 4.0,
                    },
                ),
                (
                    "high",
                    Membership::Trapezoidal {
                        a: 6.0,
                        b: 6.0,
                        c: 10.0,
                        d: 10.0,
                    },
                ),
            ],
        );
        let rules = vec![
            Rule {
                antecedent: Antecedent::Is { input: 0, term: 0 },
                term: 0,
            },
            Rule {
                antecedent: Antecedent::Is { input: 0, term: 1 },
                term: 1,
            },
        ];
        let system = Mamdani::new(vec![input], output, rules, 201).unwrap();
        // x = 0: "a" fires 1, "b" fires 0 → centroid of [0, 4] = 2.
        assert!((system.infer(&[0.0]).unwrap().unwrap() - 2.0).abs() < 1e-9);
        // The hand case: an input whose terms give "low" 1 and "high" 0.5.
        let lopsided = Mamdani::new(
            vec![Variable::new(
                "x",
                0.0,
                1.0,
                &[
                    (
                        "one",
                        Membership::Trapezoidal {
                            a: f64::NEG_INFINITY,
                            b: f64::NEG_INFINITY,
                            c: 1.0,
                            d: 1.0,
                        },
                    ),
                    (
                        "half",
                        Membership::Triangular {
                            a: -1.0,
                            b: 1.0,
                            c: 3.0,
                        },
                    ),
                ],
            )],
            system.output().clone(),
            vec![
                Rule {
                    antecedent: Antecedent::Is { input: 0, term: 0 },
                    term: 0,
                },
                Rule {
                    antecedent: Antecedent::Is { input: 0, term: 1 },
                    term: 1,
                },
            ],
            201,
        )
        .unwrap();
        // At x = 0: "one" = 1, "half" = 0.5.
        let y = lopsided.infer(&[0.0]).unwrap().unwrap();
        assert!((y - 4.0).abs() < 1e-9, "{y}");
    }

    #[test]
    fn and_or_not_and_symmetric_clipping() {
        let level = |name: &str| {
            Variable::new(
                name,
                0.0,
                1.0,
                &[
                    (
                        "lo",
                        Membership::Triangular {
                            a: 0.0,
                            b: 0.0,
                            c: 1.0,
                        },
                    ),
                    (
                        "hi",
                        Membership::Triangular {
                            a: 0.0,
                            b: 1.0,
                            c: 1.0,
                        },
                    ),
                ],
            )
        };
        let output = Variable::new(
            "y",
            0.0,
            10.0,
            &[(
                "mid",
                Membership::Triangular {
                    a: 0.0,
                    b: 5.0,
                    c: 10.0,
                },
            )],
        );
        let is = |input, term| Antecedent::Is { input, term };
        let rules = vec![
            Rule {
                antecedent: Antecedent::And(vec![is(0, 1), is(1, 1)]),
                term: 0,
            },
            Rule {
                antecedent: Antecedent::Or(vec![is(0, 1), is(1, 1)]),
                term: 0,
            },
            Rule {
                antecedent: Antecedent::Not(Box::new(is(0, 1))),
                term: 0,
            },
        ];
        let system = Mamdani::new(vec![level("p"), level("q")], output, rules, 101).unwrap();
        let w = system.firings(&[0.3, 0.8]).unwrap();
        assert!((w[0] - 0.3).abs() < EPS); // min(0.3, 0.8)
        assert!((w[1] - 0.8).abs() < EPS); // max
        assert!((w[2] - 0.7).abs() < EPS); // 1 − 0.3
        // A symmetric output set clipped at any height stays centred.
        assert!((system.infer(&[0.3, 0.8]).unwrap().unwrap() - 5.0).abs() < 1e-9);
    }

    #[test]
    fn no_rule_firing_gives_none_and_bad_systems_are_refused() {
        let input = Variable::new(
            "x",
            0.0,
            1.0,
            &[(
                "a",
                Membership::Triangular {
                    a: 0.0,
                    b: 0.5,
                    c: 1.0,
                },
            )],
        );
        let output = Variable::new(
            "y",
            0.0,
            1.0,
            &[(
                "z",
                Membership::Triangular {
                    a: 0.0,
                    b: 0.5,
                    c: 1.0,
                },
            )],
        );
        let rule = Rule {
            antecedent: Antecedent::Is { input: 0, term: 0 },
            term: 0,
        };
        let system =
            Mamdani::new(vec![input.clone()], output.clone(), vec![rule.clone()], 11).unwrap();
        assert_eq!(system.infer(&[5.0]).unwrap(), None);
        assert!(matches!(system.infer(&[]), Err(FuzzyError::Inputs { .. })));
        let bad_rule = Rule {
            antecedent: Antecedent::Is { input: 1, term: 0 },
            term: 0,
        };
        assert_eq!(
            Mamdani::new(vec![input.clone()], output.clone(), vec![bad_rule], 11),
            Err(FuzzyError::Index)
        );
        let bad_shape = Variable::new(
            "x",
            0.0,
            1.0,
            &[(
                "a",
                Membership::Triangular {
                    a: 1.0,
                    b: 0.5,
                    c: 0.0,
                },
            )],
        );
        assert!(matches!(
            Mamdani::new(vec![bad_shape], output, vec![rule], 11),
            Err(FuzzyError::Shape(_))
        ));
        assert_eq!(
            input.term("nope").unwrap_err().to_string(),
            "variable `x` has no term `nope`"
        );
    }
}
