//! Integer encoding of RDF terms: the reasoner works on `[Id; 3]` facts.

use oxrdf::{NamedNode, Term};
use rustc_hash::FxHashMap;

/// The identifier of a term in a [`Dictionary`].
pub type Id = u32;

/// A fact: subject, predicate, object, as term identifiers.
pub type Fact = [Id; 3];

/// A two-way map between terms and identifiers.
///
/// Terms of the schema (encoded before [`Dictionary::pin`]) live as long as the dictionary.
/// Every other term is counted in the explicit facts that use it and released once none does
/// ([`Dictionary::release_unused`]): its identifier is then given to the next new term. A
/// service whose data keeps changing (CUs respawned under new names, change sets recorded and
/// pruned) so keeps a dictionary the size of its current data, not of its history. Releasing
/// is sound because OWL 2 RL rules invent no terms: a term no explicit or schema fact uses is
/// in no fact of the materialisation either.
#[derive(Debug, Default, Clone)]
pub struct Dictionary {
    terms: Vec<Term>,
    literal: Vec<bool>,
    ids: FxHashMap<Term, Id>,
    /// Per identifier: the explicit facts that use it (a fact using it twice counts twice).
    uses: Vec<u32>,
    /// Per identifier: whether it is allocated (not released).
    live: Vec<bool>,
    /// Identifiers below this one are never released.
    pinned: Id,
    /// Released identifiers, given out again before new ones.
    free: Vec<Id>,
    /// Identifiers whose use count fell to zero (or that were allocated unused) since the last
    /// [`Dictionary::release_unused`].
    unused: Vec<Id>,
}

impl Dictionary {
    /// The identifier of `term`, allocated if new.
    pub fn encode(&mut self, term: impl Into<Term>) -> Id {
        let term = term.into();
        if let Some(id) = self.ids.get(&term) {
            return *id;
        }
        let literal = matches!(term, Term::Literal(_));
        let id = if let Some(id) = self.free.pop() {
            let i = id as usize;
            self.terms[i] = term.clone();
            self.literal[i] = literal;
            self.uses[i] = 0;
            self.live[i] = true;
            id
        } else {
            let id = Id::try_from(self.terms.len()).unwrap_or(Id::MAX);
            self.terms.push(term.clone());
            self.literal.push(literal);
            self.uses.push(0);
            self.live.push(true);
            id
        };
        self.ids.insert(term, id);
        self.unused.push(id);
        id
    }

    /// The identifier of `term`, if it is encoded.
    pub fn get(&self, term: &Term) -> Option<Id> {
        self.ids.get(term).copied()
    }

    /// The term of `id`.
    ///
    /// # Panics
    /// If `id` was not allocated by this dictionary.
    pub fn decode(&self, id: Id) -> &Term {
        &self.terms[id as usize]
    }

    /// Whether `id` is a literal (literals cannot be subjects).
    pub fn is_literal(&self, id: Id) -> bool {
        self.literal.get(id as usize).copied().unwrap_or(false)
    }

    /// Makes every term encoded so far permanent (the schema's: rules refer to them).
    pub fn pin(&mut self) {
        self.pinned = Id::try_from(self.terms.len()).unwrap_or(Id::MAX);
        self.unused.clear();
    }

    /// Counts one more explicit fact using `id` (once per position it holds).
    pub fn add_use(&mut self, id: Id) {
        if let Some(n) = self.uses.get_mut(id as usize) {
            *n += 1;
        }
    }

    /// Counts one explicit fact less using `id`.
    pub fn remove_use(&mut self, id: Id) {
        if let Some(n) = self.uses.get_mut(id as usize) {
            *n = n.saturating_sub(1);
            if *n == 0 {
                self.unused.push(id);
            }
        }
    }

    /// Releases every unpinned term no explicit fact uses any more. The caller guarantees that
    /// no fact it keeps refers to them (true once an update is complete: see the type's
    /// documentation).
    pub fn release_unused(&mut self) {
        let placeholder = Term::NamedNode(NamedNode::new_unchecked(String::new()));
        for id in std::mem::take(&mut self.unused) {
            let i = id as usize;
            if id < self.pinned || !self.live[i] || self.uses[i] != 0 {
                continue;
            }
            let term = std::mem::replace(&mut self.terms[i], placeholder.clone());
            self.ids.remove(&term);
            self.live[i] = false;
            self.literal[i] = false;
            self.free.push(id);
        }
    }

    /// The number of terms encoded (released ones excluded).
    pub fn len(&self) -> usize {
        self.terms.len() - self.free.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn iri(s: &str) -> Term {
        NamedNode::new_unchecked(format!("http://example.org/{s}")).into()
    }

    #[test]
    fn unused_terms_are_released_and_their_ids_reused_pinned_ones_never() {
        let mut d = Dictionary::default();
        let schema = d.encode(iri("schema"));
        d.pin();
        let a = d.encode(iri("a"));
        let b = d.encode(iri("b"));
        d.add_use(a);
        d.add_use(a);
        d.release_unused();
        // b was never used: released; a is used twice.
        assert_eq!(d.len(), 2);
        assert_eq!(d.get(&iri("b")), None);
        assert_eq!(d.get(&iri("a")), Some(a));
        d.remove_use(a);
        d.release_unused();
        assert_eq!(d.get(&iri("a")), Some(a), "one use left");
        d.remove_use(a);
        d.release_unused();
        assert_eq!(d.get(&iri("a")), None);
        assert_eq!(d.get(&iri("schema")), Some(schema), "pinned");
        // Released identifiers are given out again, with their new term.
        let c = d.encode(iri("c"));
        assert!(c == a || c == b, "{c} reuses a released identifier");
        assert_eq!(d.decode(c), &iri("c"));
        assert_eq!(d.len(), 2);
        let lit: Term = oxrdf::Literal::new_simple_literal("x").into();
        let l = d.encode(lit.clone());
        assert!(d.is_literal(l));
        d.release_unused();
        assert_eq!(d.len(), 1, "c and the literal were unused");
        let n = d.encode(iri("n"));
        assert!(
            !d.is_literal(n),
            "a reused identifier forgets it was a literal"
        );
    }
}
