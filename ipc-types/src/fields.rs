//! Each message's fields as data, from one declaration per message.
//!
//! A message type is declared once, through `message!`: the macro emits the
//! struct as written and, from the same field list, its [`Fields`] implementation: a visitor
//! over the fields by name and value ([`Fields::visit`]), the type's memory layout
//! ([`Fields::layout`], what [`crate::layout::describe`] lists) and the fields a replay of the
//! process that produced the message does not compare ([`Fields::NOT_REPLAYED`], declared next
//! to the message with the reason). A field added to a message is thereby visited, described
//! and compared by `scl replay` with no other edit.
//!
//! The bit sets (`buttons`, `safe_flags`, ...) are declared through `bits!`:
//! each bit once, with its short name; the names array (`NAMES`) follows from it.

use std::fmt;

use crate::control::Text;
use crate::layout::TypeLayout;

/// A field's value, borrowed from the message: a scalar, the elements of an array, or a
/// nested struct.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value<'a> {
    /// A `u8`.
    U8(u8),
    /// A `u16`.
    U16(u16),
    /// A `u32`.
    U32(u32),
    /// A `u64`.
    U64(u64),
    /// An `i32`.
    I32(i32),
    /// An `i64`.
    I64(i64),
    /// An `f32`.
    F32(f32),
    /// An `f64`.
    F64(f64),
    /// A `[u8; N]`.
    U8s(&'a [u8]),
    /// A `[u16; N]`.
    U16s(&'a [u16]),
    /// A `[u32; N]`.
    U32s(&'a [u32]),
    /// A `[u64; N]`.
    U64s(&'a [u64]),
    /// An `[i32; N]`.
    I32s(&'a [i32]),
    /// An `[i64; N]`.
    I64s(&'a [i64]),
    /// An `[f32; N]`.
    F32s(&'a [f32]),
    /// An `[f64; N]`.
    F64s(&'a [f64]),
    /// A [`Text`].
    Text(&'a Text),
}

/// The value as Rust's `Debug` writes the field (`3`, `1.5`, `[1, 2]`); a [`Text`] as its
/// string, quoted.
impl fmt::Display for Value<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::U8(v) => write!(f, "{v:?}"),
            Self::U16(v) => write!(f, "{v:?}"),
            Self::U32(v) => write!(f, "{v:?}"),
            Self::U64(v) => write!(f, "{v:?}"),
            Self::I32(v) => write!(f, "{v:?}"),
            Self::I64(v) => write!(f, "{v:?}"),
            Self::F32(v) => write!(f, "{v:?}"),
            Self::F64(v) => write!(f, "{v:?}"),
            Self::U8s(v) => write!(f, "{v:?}"),
            Self::U16s(v) => write!(f, "{v:?}"),
            Self::U32s(v) => write!(f, "{v:?}"),
            Self::U64s(v) => write!(f, "{v:?}"),
            Self::I32s(v) => write!(f, "{v:?}"),
            Self::I64s(v) => write!(f, "{v:?}"),
            Self::F32s(v) => write!(f, "{v:?}"),
            Self::F64s(v) => write!(f, "{v:?}"),
            Self::Text(v) => write!(f, "{:?}", v.as_string()),
        }
    }
}

/// The type of a message field: its name as bindings spell it (`u64`, `f32`, `[f64; 8]`, or
/// the name of a nested struct, `Text`) and its [`Value`].
pub trait FieldType {
    /// The type's name.
    fn describe() -> String;
    /// The value of a field of this type.
    fn value(&self) -> Value<'_>;
}

/// A scalar type an array field may hold: how a slice of it is a [`Value`].
pub trait Element: FieldType + Sized {
    /// The elements of an array field.
    fn elements(s: &[Self]) -> Value<'_>;
}

macro_rules! primitive {
    ($($t:ty => $one:ident, $many:ident;)*) => {$(
        impl FieldType for $t {
            fn describe() -> String {
                stringify!($t).to_owned()
            }
            fn value(&self) -> Value<'_> {
                Value::$one(*self)
            }
        }
        impl Element for $t {
            fn elements(s: &[Self]) -> Value<'_> {
                Value::$many(s)
            }
        }
    )*};
}
primitive! {
    u8 => U8, U8s;
    u16 => U16, U16s;
    u32 => U32, U32s;
    u64 => U64, U64s;
    i32 => I32, I32s;
    i64 => I64, I64s;
    f32 => F32, F32s;
    f64 => F64, F64s;
}

impl<T: Element, const N: usize> FieldType for [T; N] {
    fn describe() -> String {
        format!("[{}; {N}]", T::describe())
    }
    fn value(&self) -> Value<'_> {
        T::elements(self)
    }
}

impl FieldType for Text {
    fn describe() -> String {
        "Text".to_owned()
    }
    fn value(&self) -> Value<'_> {
        Value::Text(self)
    }
}

/// A message declared through `message!`: its fields by name, in
/// declaration order.
pub trait Fields: Sized {
    /// The fields `scl replay` does not compare when it re-runs the step that produced the
    /// message: the producing process's own stamps (when it received its inputs, how long it
    /// computed, when it published), which the replayed step does not compute, and padding.
    /// Empty for a message no step of the replay produces. Each message gives its reasons.
    const NOT_REPLAYED: &'static [&'static str];

    /// Calls `f` with each field's name and value, in declaration order.
    fn visit<'a>(&'a self, f: &mut dyn FnMut(&'static str, Value<'a>));

    /// The type's memory layout: size, alignment, iceoryx2 type name, every field's offset,
    /// size and type.
    fn layout() -> TypeLayout;

    /// The fields' names and values, in declaration order.
    fn fields(&self) -> Vec<(&'static str, Value<'_>)> {
        let mut out = Vec::new();
        self.visit(&mut |name, v| out.push((name, v)));
        out
    }
}

/// Declares a message type once: the struct as written (attributes, doc comments and all;
/// every field `pub`) and its [`Fields`] implementation from the same field list. An optional
/// `not_replayed: [field, ...];` after the struct, with its reasons as doc comments, lists the
/// fields `scl replay` does not compare ([`Fields::NOT_REPLAYED`]); each must be a field.
macro_rules! message {
    (
        $(#[$meta:meta])*
        pub struct $t:ident {
            $(
                $(#[$fmeta:meta])*
                pub $f:ident: $ty:ty
            ),* $(,)?
        }
        $(
            $(#[$nmeta:meta])*
            not_replayed: [$($skip:ident),* $(,)?];
        )?
    ) => {
        $(#[$meta])*
        pub struct $t {
            $(
                $(#[$fmeta])*
                pub $f: $ty,
            )*
        }

        impl $crate::fields::Fields for $t {
            $($(#[$nmeta])*)?
            const NOT_REPLAYED: &'static [&'static str] = &[$($(stringify!($skip)),*)?];

            fn visit<'a>(
                &'a self,
                f: &mut dyn FnMut(&'static str, $crate::fields::Value<'a>),
            ) {
                $(f(stringify!($f), $crate::fields::FieldType::value(&self.$f));)*
            }

            fn layout() -> $crate::layout::TypeLayout {
                $crate::layout::TypeLayout {
                    name: stringify!($t),
                    // SAFETY: `type_name` only returns the string given to the derive.
                    type_name: unsafe {
                        <$t as ::iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend>::type_name()
                    },
                    size: ::core::mem::size_of::<$t>(),
                    align: ::core::mem::align_of::<$t>(),
                    fields: vec![$($crate::layout::FieldLayout {
                        name: stringify!($f),
                        offset: ::core::mem::offset_of!($t, $f),
                        size: ::core::mem::size_of::<$ty>(),
                        ty: <$ty as $crate::fields::FieldType>::describe(),
                    }),*],
                }
            }
        }

        // The fields not replayed are fields of the message.
        const _: () = {
            #[allow(dead_code, unused_variables)]
            fn not_replayed_are_fields(v: &$t) {
                $($(let _ = &v.$skip;)*)?
            }
        };
    };
}
pub(crate) use message;

/// Declares a set of `u32` flag bits once: each bit's constant (`NAME = 1 << i, "short-name";`,
/// with its doc comment) and `NAMES`, the short names in bit order. The bits must be
/// declared in order from bit 0 without gaps (checked at compile time), so `NAMES[i]` names
/// bit `i`.
macro_rules! bits {
    ($(
        $(#[$meta:meta])*
        $name:ident = 1 << $bit:literal, $short:literal;
    )*) => {
        $(
            $(#[$meta])*
            pub const $name: u32 = 1 << $bit;
        )*
        /// Short names of the bits, in bit order.
        pub const NAMES: [&str; [$($short),*].len()] = [$($short),*];
        // `NAMES[i]` names bit `i`: the bits are declared in order from bit 0, without gaps.
        const _: () = {
            let bits: &[u32] = &[$($bit),*];
            let mut i = 0;
            while i < bits.len() {
                assert!(bits[i] as usize == i, "bits declared out of order or with a gap");
                i += 1;
            }
        };
    };
}
pub(crate) use bits;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::{ControlRequest, ControlResponse, EstopCommand, SafetyControl};
    use crate::msg::*;
    use zerocopy::FromZeros;

    /// The names `visit` gives, against the layout's.
    fn visits_as_described<T: Fields>(v: &T) {
        let visited: Vec<_> = v.fields().into_iter().map(|(n, _)| n).collect();
        let described: Vec<_> = T::layout().fields.iter().map(|f| f.name).collect();
        assert_eq!(visited, described, "{}", T::layout().name);
        for n in T::NOT_REPLAYED {
            assert!(visited.contains(n), "{n}");
        }
    }

    #[test]
    fn every_field_is_visited_in_declaration_order() {
        visits_as_described(&JoystickInput::neutral(1));
        visits_as_described(&RobotState::at_rest(0, 1, 6));
        visits_as_described(&MapperCommand::new_zeroed());
        visits_as_described(&SafeCommand::zeroed());
        visits_as_described(&TickReport::new_zeroed());
        visits_as_described(&NodeStatus::new(NodeRole::Bridge, phase::READY, 0));
        visits_as_described(&SafetyControl::new_zeroed());
        visits_as_described(&EstopCommand::new_zeroed());
        visits_as_described(&Text::new("x"));
        visits_as_described(&ControlRequest {
            kind: 1,
            reserved: 0,
            path: Text::new("/m"),
        });
        visits_as_described(&ControlResponse::refused("no"));
    }

    #[test]
    fn values_are_the_fields() {
        let mut c = SafeCommand::zeroed();
        c.tick = 7;
        c.qdot_rad_s[1] = 0.5;
        c.closest_pair = [3, 4];
        let f = c.fields();
        assert_eq!(f[0], ("tick", Value::U64(7)));
        let q = f.iter().find(|(n, _)| *n == "qdot_rad_s").unwrap().1;
        assert_eq!(q, Value::F64s(&c.qdot_rad_s));
        let pair = f.iter().find(|(n, _)| *n == "closest_pair").unwrap().1;
        assert_eq!(pair.to_string(), "[3, 4]");
        assert_eq!(Value::F64(1.0).to_string(), "1.0");
        assert_eq!(Value::Text(&Text::new("a b")).to_string(), "\"a b\"");
        assert_eq!(
            MapperCommand::NOT_REPLAYED,
            ["t_ns", "state_rx_ns", "joystick_rx_ns", "compute_ns"]
        );
        assert!(JoystickInput::NOT_REPLAYED.is_empty());
    }
}
