//! The candidate table (the seed's validity matrix, Ch. 4.3): for every in port of every
//! transformation and for every target, the out ports whose tags satisfy it under the
//! similarity relation ~. The knowledge base computes it with one SPARQL query
//! ([`crate::knowledge`]); tests build it from any relation ([`Candidates::from_tags`]).

use std::collections::BTreeMap;

use rustc_hash::FxHashMap;

use crate::ids::{Qid, Tid};
use crate::model::Environment;

/// An out port that can satisfy an in port or a target: the port `port` (an index into the
/// transformation's outputs) of transformation `tid`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Provider {
    /// The producing transformation.
    pub tid: Tid,
    /// The index of its out port.
    pub port: usize,
}

/// The candidate table.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Candidates {
    /// Per transformation, per in port with at least one provider (never an empty list, nor
    /// a transformation without one): looked up by `&str` without building a key.
    inputs: FxHashMap<Tid, BTreeMap<usize, Vec<Provider>>>,
    targets: FxHashMap<Qid, Vec<Provider>>,
}

impl Candidates {
    /// Records that `provider` satisfies in port `input` of `tid`.
    pub fn add_input(&mut self, tid: &str, input: usize, provider: Provider) {
        // A key is built only for a transformation not in the table yet.
        let ports = match self.inputs.get_mut(tid) {
            Some(ports) => ports,
            None => self.inputs.entry(Tid::from(tid)).or_default(),
        };
        let list = ports.entry(input).or_default();
        if !list.contains(&provider) {
            list.push(provider);
            list.sort();
        }
    }

    /// Records that `provider` satisfies target `qid`.
    pub fn add_target(&mut self, qid: &str, provider: Provider) {
        let list = match self.targets.get_mut(qid) {
            Some(list) => list,
            None => self.targets.entry(Qid::from(qid)).or_default(),
        };
        if !list.contains(&provider) {
            list.push(provider);
            list.sort();
        }
    }

    /// Sets the providers of in port `input` of `tid` (sorted and deduplicated here); none
    /// removes the entry, as if it had never been added to.
    pub fn set_input(&mut self, tid: &str, input: usize, mut providers: Vec<Provider>) {
        providers.sort();
        providers.dedup();
        if !providers.is_empty() {
            match self.inputs.get_mut(tid) {
                Some(ports) => ports.insert(input, providers),
                None => self
                    .inputs
                    .entry(Tid::from(tid))
                    .or_default()
                    .insert(input, providers),
            };
        } else if let Some(ports) = self.inputs.get_mut(tid) {
            ports.remove(&input);
            if ports.is_empty() {
                self.inputs.remove(tid);
            }
        }
    }

    /// Sets the providers of target `qid`, as [`Candidates::set_input`] does.
    pub fn set_target(&mut self, qid: &str, mut providers: Vec<Provider>) {
        providers.sort();
        providers.dedup();
        if providers.is_empty() {
            self.targets.remove(qid);
        } else if let Some(list) = self.targets.get_mut(qid) {
            *list = providers;
        } else {
            self.targets.insert(Qid::from(qid), providers);
        }
    }

    /// How many in ports and targets have at least one provider.
    pub fn len(&self) -> usize {
        self.inputs.values().map(BTreeMap::len).sum::<usize>() + self.targets.len()
    }

    /// Whether no in port or target has a provider.
    pub fn is_empty(&self) -> bool {
        self.inputs.is_empty() && self.targets.is_empty()
    }

    /// The providers of in port `input` of `tid`, sorted.
    pub fn for_input(&self, tid: &str, input: usize) -> &[Provider] {
        self.inputs
            .get(tid)
            .and_then(|ports| ports.get(&input))
            .map_or(&[], Vec::as_slice)
    }

    /// The providers of target `qid`, sorted.
    pub fn for_target(&self, qid: &str) -> &[Provider] {
        self.targets.get(qid).map_or(&[], Vec::as_slice)
    }

    /// Builds the table from tags: `in_tags(tid, i)`, `out_tags(tid, j)` and `target_tags(qid)`
    /// give the tags of ports and targets, `similar(i, o)` is the relation `i ~ o`.
    pub fn from_tags<T>(
        env: &Environment,
        in_tags: impl Fn(&str, usize) -> Vec<T>,
        out_tags: impl Fn(&str, usize) -> Vec<T>,
        target_tags: impl Fn(&str) -> Vec<T>,
        similar: impl Fn(&T, &T) -> bool,
    ) -> Self {
        let mut table = Self::default();
        let outs: Vec<(Provider, Vec<T>)> = env
            .library
            .values()
            .flat_map(|t| {
                (0..t.outputs.len()).map(|j| {
                    (
                        Provider {
                            tid: t.tid.clone(),
                            port: j,
                        },
                        out_tags(&t.tid, j),
                    )
                })
            })
            .collect();
        let matches = |wanted: &[T]| -> Vec<Provider> {
            outs.iter()
                .filter(|(_, have)| wanted.iter().any(|w| have.iter().any(|h| similar(w, h))))
                .map(|(p, _)| p.clone())
                .collect()
        };
        for t in env.library.values() {
            for i in 0..t.inputs.len() {
                for p in matches(&in_tags(&t.tid, i)) {
                    table.add_input(&t.tid, i, p);
                }
            }
        }
        for q in env.targets.keys() {
            for p in matches(&target_tags(q)) {
                table.add_target(q, p);
            }
        }
        table
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(tid: &str, port: usize) -> Provider {
        Provider {
            tid: Tid::from(tid),
            port,
        }
    }

    /// The incremental table is compared with one computed from scratch: a table whose lists
    /// were emptied again must equal one that never had them.
    #[test]
    fn a_table_emptied_again_equals_one_never_filled() {
        let mut table = Candidates::default();
        table.set_input("a", 0, vec![p("c", 0), p("b", 1), p("b", 1)]);
        table.add_input("a", 1, p("c", 0));
        table.add_target("q", p("a", 0));
        assert_eq!(table.len(), 3);
        assert_eq!(
            table.for_input("a", 0),
            [p("b", 1), p("c", 0)],
            "sorted, once each"
        );
        assert_eq!(table.for_input("a", 2), []);
        assert_eq!(table.for_input("z", 0), []);
        // Setting a list that exists replaces it (the key is kept, not built again).
        table.set_input("a", 0, vec![p("d", 0)]);
        assert_eq!(table.for_input("a", 0), [p("d", 0)]);
        table.set_target("q", vec![p("b", 0), p("a", 0)]);
        assert_eq!(table.for_target("q"), [p("a", 0), p("b", 0)]);
        table.add_target("q", p("a", 0));
        assert_eq!(table.for_target("q"), [p("a", 0), p("b", 0)], "once each");
        table.set_target("q", vec![p("a", 0)]);
        table.set_input("a", 0, Vec::new());
        assert_eq!(table.len(), 2);
        assert_eq!(table.for_input("a", 1), [p("c", 0)]);
        table.set_input("a", 1, Vec::new());
        table.set_target("q", Vec::new());
        assert!(table.is_empty());
        assert_eq!(table, Candidates::default());
    }
}
