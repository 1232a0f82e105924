//! [`setters!`](crate::setters): the chainable setters of the `#[non_exhaustive]` options
//! structs.

/// Chainable setters for an options struct, one per field: inside an `impl` block, each
/// entry `with_field(field: Type);` becomes
///
/// ```text
/// /// These options with [`field`](Self::field) set to `value`.
/// #[must_use]
/// pub fn with_field(mut self, value: Type) -> Self {
///     self.field = value;
///     self
/// }
/// ```
///
/// An entry with doc comments of its own gets those in place of the generated sentence.
/// Options structs are `#[non_exhaustive]`, so code outside their crate cannot use
/// struct-literal syntax: it starts from `Default` (or a preset) and chains these.
///
/// ```
/// #[derive(Debug, Default)]
/// #[non_exhaustive]
/// pub struct FitOptions {
///     /// Optimisation steps.
///     pub steps: usize,
///     /// Smallest and largest edge length.
///     pub edge_len_lims: (f32, f32),
/// }
///
/// impl FitOptions {
///     w3d_core::setters! {
///         with_steps(steps: usize);
///         /// These options with [`edge_len_lims`](Self::edge_len_lims) set to `value`
///         /// (smallest first).
///         with_edge_len_lims(edge_len_lims: (f32, f32));
///     }
/// }
///
/// let options = FitOptions::default().with_steps(20).with_edge_len_lims((0.01, 0.03));
/// assert_eq!((options.steps, options.edge_len_lims), (20, (0.01, 0.03)));
/// ```
#[macro_export]
macro_rules! setters {
    (@setter [] $setter:ident $field:ident $ty:ty) => {
        #[doc = concat!("These options with [`", stringify!($field), "`](Self::", stringify!($field), ") set to `value`.")]
        #[must_use]
        pub fn $setter(mut self, value: $ty) -> Self {
            self.$field = value;
            self
        }
    };
    (@setter [$($doc:literal)+] $setter:ident $field:ident $ty:ty) => {
        $(#[doc = $doc])+
        #[must_use]
        pub fn $setter(mut self, value: $ty) -> Self {
            self.$field = value;
            self
        }
    };
    ($($(#[doc = $doc:literal])* $setter:ident($field:ident: $ty:ty);)*) => {
        $($crate::setters!(@setter [$($doc)*] $setter $field $ty);)*
    };
}
