// The toolpath file parser ([creep.edge] toolpath_file): normals and / or removal cross-sections.
#include "core/creep/toolpath.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <string>

namespace nccomp::core::creep {
namespace {

std::string error_of(const std::string& text) {
  try {
    (void)parse_toolpath(text, "part.csv");
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

const std::string kHeaders =
    "expected the header 'path_mm,nx,ny,nz', 'path_mm,nx,ny,nz,removal_mm2' or "
    "'path_mm,removal_mm2'";

TEST(CreepToolpath, ParsesRowsCommentsAndCrlfAndNormalises) {
  const auto t = parse_toolpath(
      "# from CAM\r\npath_mm, nx, ny, nz\r\n\r\n0.0,0,0,1\r\n15,0,-0.6,0.8\r\n30,0.995,0,0\r\n",
      "part.csv");
  EXPECT_TRUE(t.has_normals);
  EXPECT_FALSE(t.has_removal);
  ASSERT_EQ(t.rows.size(), 3U);
  EXPECT_NEAR(t.rows[1].path_mm, 15.0, 0.0);
  EXPECT_NEAR(t.rows[1].normal[1], -0.6, 1e-12);
  EXPECT_NEAR(t.rows[2].normal[0], 1.0, 1e-12);  // |n| = 0.995 is normalised
  EXPECT_TRUE(std::isnan(t.rows[2].removal_mm2));
}

TEST(CreepToolpath, ReadsTheRemovalCrossSectionWithOrWithoutNormals) {
  const auto both = parse_toolpath(
      "path_mm,nx,ny,nz,removal_mm2\n0,0,0,1,0.5\n100,0,0,1,2.25\n200,1,0,0,0\n", "part.csv");
  EXPECT_TRUE(both.has_normals);
  EXPECT_TRUE(both.has_removal);
  ASSERT_EQ(both.rows.size(), 3U);
  EXPECT_NEAR(both.rows[1].removal_mm2, 2.25, 0.0);
  EXPECT_NEAR(both.rows[2].normal[0], 1.0, 0.0);
  const auto only = parse_toolpath("path_mm,removal_mm2\n0,0.5\n100,2\n", "part.csv");
  EXPECT_FALSE(only.has_normals);
  EXPECT_TRUE(only.has_removal);
  ASSERT_EQ(only.rows.size(), 2U);
  EXPECT_NEAR(only.rows[0].removal_mm2, 0.5, 0.0);
}

TEST(CreepToolpath, ErrorsNameFileAndLine) {
  EXPECT_EQ(error_of("path,nx,ny,nz\n0,0,0,1\n1,0,0,1\n"), "part.csv:1: " + kHeaders);
  EXPECT_EQ(error_of("path_mm,nx,ny,nz,removal\n0,0,0,1,1\n1,0,0,1,1\n"),
            "part.csv:1: " + kHeaders);
  EXPECT_EQ(error_of("path_mm,nx,ny,nz\n0,0,0,1\n1,0,0\n"),
            "part.csv:3: expected 4 columns, got 3");
  EXPECT_EQ(error_of("path_mm,nx,ny,nz\n0,0,0,1\n1,0,x,1\n"),
            "part.csv:3: ny is not a finite number: 'x'");
  EXPECT_EQ(error_of("path_mm,nx,ny,nz\n0,0,0,1\n1,0,0,nan\n"),
            "part.csv:3: nz is not a finite number: 'nan'");
  EXPECT_NE(
      error_of("path_mm,nx,ny,nz\n0,0,0,1\n1,0,0,2\n").find("part.csv:3: normal is not a unit"),
      std::string::npos);
  EXPECT_NE(error_of("path_mm,nx,ny,nz\n5,0,0,1\n5,0,0,1\n").find("part.csv:3: path_mm must be"),
            std::string::npos);
  EXPECT_EQ(error_of("path_mm,nx,ny,nz\n0,0,0,1\n"), "part.csv:3: needs at least 2 rows");
  EXPECT_EQ(error_of(""), "part.csv:1: empty file: " + kHeaders);
  EXPECT_EQ(error_of("path_mm,nx,ny,nz\n0,0,0,1,7\n"), "part.csv:2: expected 4 columns, got 5");
  EXPECT_EQ(error_of("path_mm,removal_mm2\n0,1\n5,-0.5\n"),
            "part.csv:3: removal_mm2 must be 0..10000 mm², got -0.5");
  EXPECT_EQ(error_of("path_mm,removal_mm2\n0,1\n5,2e4\n"),
            "part.csv:3: removal_mm2 must be 0..10000 mm², got 2e4");
  EXPECT_EQ(error_of("path_mm,removal_mm2\n0,1\n5,inf\n"),
            "part.csv:3: removal_mm2 is not a finite number: 'inf'");
  EXPECT_EQ(error_of("path_mm,removal_mm2\n0,1\n5,1,2\n"), "part.csv:3: expected 2 columns, got 3");
}

}  // namespace
}  // namespace nccomp::core::creep
