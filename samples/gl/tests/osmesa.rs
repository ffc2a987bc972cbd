//! The render checks of `common` through the OSMesa route (`libOSMesa.so.8`, Mesa llvmpipe).

mod common;

use ndfmap_gl::Route;

common::route_tests!(Route::OsMesa);
