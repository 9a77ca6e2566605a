#include "language/lexer.h"

#include <cctype>
#include <cstring>

#include "internal_text.h"
#include "pk/error.h"

namespace pk {
namespace internal {
namespace lang {
namespace {

bool IsIdentStart(char c) { return AsciiAlpha(c) || c == '_'; }
bool IsIdentChar(char c) { return AsciiAlnum(c) || c == '_' || c == '.'; }
bool IsDigit(char c) { return AsciiDigit(c); }

class Lexer {
 public:
  Lexer(const std::string& text, const std::string& source) : t_(text), source_(source) {}

  std::vector<Token> Run() {
    while (i_ < t_.size()) {
      const char c = t_[i_];
      if (c == '\n') {
        if (depth_ == 0) Push(Token::Kind::kNewline, "\n", i_, 1);
        Advance(1);
        ++line_;
        line_start_ = i_;
      } else if (c == ' ' || c == '\t' || c == '\r') {
        Advance(1);
      } else if (c == '#' || c == ';') {
        while (i_ < t_.size() && t_[i_] != '\n') Advance(1);
      } else if (c == '$') {
        Block();
      } else if (IsIdentStart(c)) {
        size_t j = i_;
        while (j < t_.size() && IsIdentChar(t_[j])) ++j;
        Push(Token::Kind::kIdentifier, t_.substr(i_, j - i_), i_, j - i_);
        Advance(j - i_);
      } else if (IsDigit(c) || (c == '.' && i_ + 1 < t_.size() && IsDigit(t_[i_ + 1]))) {
        Number();
      } else {
        Punct();
      }
    }
    Push(Token::Kind::kNewline, "\n", i_, 0);
    Push(Token::Kind::kEnd, "", i_, 0);
    return std::move(tokens_);
  }

 private:
  [[noreturn]] void Fail(size_t at, const std::string& message) const {
    throw InputError(source_, line_, static_cast<int>(at - line_start_) + 1, message);
  }
  void Advance(size_t n) { i_ += n; }
  void Push(Token::Kind kind, std::string text, size_t at, size_t length) {
    Token tok;
    tok.kind = kind;
    tok.text = std::move(text);
    tok.line = line_;
    tok.column = static_cast<int>(at - line_start_) + 1;
    tok.offset = at;
    tok.length = length;
    tokens_.push_back(std::move(tok));
  }

  void Block() {
    size_t j = i_ + 1;
    while (j < t_.size() && IsIdentChar(t_[j])) ++j;
    if (j == i_ + 1) Fail(i_, "expected a block name after '$' (for example $PARAM)");
    const size_t at = i_;
    const std::string name = ToUpper(t_.substr(i_ + 1, j - i_ - 1));
    Push(Token::Kind::kBlock, name, at, j - at);
    Advance(j - i_);
    if (name != "PROBLEM" && name != "PROB") return;
    // The rest of the line is free text: the model's name and description.
    size_t end = i_;
    while (end < t_.size() && t_[end] != '\n') ++end;
    Push(Token::Kind::kText, Trim(t_.substr(i_, end - i_)), i_, end - i_);
    Advance(end - i_);
  }

  void Number() {
    size_t j = i_;
    while (j < t_.size() && IsDigit(t_[j])) ++j;
    if (j < t_.size() && t_[j] == '.') {
      ++j;
      while (j < t_.size() && IsDigit(t_[j])) ++j;
    }
    if (j < t_.size() && (t_[j] == 'e' || t_[j] == 'E')) {
      size_t k = j + 1;
      if (k < t_.size() && (t_[k] == '+' || t_[k] == '-')) ++k;
      if (k < t_.size() && IsDigit(t_[k])) {
        while (k < t_.size() && IsDigit(t_[k])) ++k;
        j = k;
      }
    }
    if (j < t_.size() && (IsIdentChar(t_[j]))) {
      size_t k = j;
      while (k < t_.size() && IsIdentChar(t_[k])) ++k;
      Fail(i_, "malformed number '" + Printable(t_.substr(i_, k - i_)) +
                   "' (a name must start with a letter or '_')");
    }
    Token::Kind kind = Token::Kind::kNumber;
    Push(kind, t_.substr(i_, j - i_), i_, j - i_);
    if (!ParseDouble(tokens_.back().text, &tokens_.back().number)) {
      Fail(i_, "number '" + tokens_.back().text + "' is out of range");
    }
    Advance(j - i_);
  }

  void Punct() {
    static const char* const kTwo[] = {"**", "<=", ">=", "==", "!=", "&&", "||"};
    for (const char* p : kTwo) {
      if (t_.compare(i_, 2, p) == 0) {
        Push(Token::Kind::kPunct, p, i_, 2);
        Advance(2);
        return;
      }
    }
    const char c = t_[i_];
    if (c == '\0') Fail(i_, "a NUL byte in the model text");
    if (std::strchr("+-*/^(),=~<>!{}", c) == nullptr) {
      Fail(i_, "unexpected character '" + Printable(std::string(1, c)) + "'");
    }
    if (c == '(') ++depth_;
    if (c == ')' && depth_ > 0) --depth_;
    Push(Token::Kind::kPunct, std::string(1, c), i_, 1);
    Advance(1);
  }

  const std::string& t_;
  const std::string& source_;
  size_t i_ = 0;
  int line_ = 1;
  size_t line_start_ = 0;
  int depth_ = 0;
  std::vector<Token> tokens_;
};

}  // namespace

std::vector<Token> Tokenize(const std::string& text, const std::string& source) {
  return Lexer(text, source).Run();
}

}  // namespace lang
}  // namespace internal
}  // namespace pk
